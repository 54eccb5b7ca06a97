"""``AlbumentationsCameraDegrade``: a camera profile as an albumentations transform (numpy HWC in and out).

Needs albumentations 2 or later (``pip install 'camdegrade[albumentations]'``). Importing this module registers the
transform with albumentations' serialisation, so ``A.from_dict`` can rebuild pipelines that hold it.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np
import torch

try:
    from albumentations.core.transforms_interface import ImageOnlyTransform
except ModuleNotFoundError as error:  # pragma: no cover - only without the extra
    raise ModuleNotFoundError(
        "camdegrade.integrations.albumentations needs albumentations>=2: pip install 'camdegrade[albumentations]'"
    ) from error

from camdegrade._checks import check_probability
from camdegrade.inference import Precision
from camdegrade.profile import CameraProfile
from camdegrade.transform import CameraDegrade

#: Seeds for the torch generator are drawn from ``[0, 2**63)``, a range ``torch.Generator.manual_seed`` accepts.
_SEED_BOUND = 2**63


class AlbumentationsCameraDegrade(ImageOnlyTransform):
    """Make images look as if the profile's camera had captured them, inside an ``A.Compose`` pipeline.

    Images are numpy arrays ``(H, W, 3)`` (target ``image``) or ``(N, H, W, 3)`` (target ``images``), uint8 or
    float in ``[0, 1]``; they come back with the same shape and dtype, in a new array. Masks, boxes and keypoints
    pass through untouched. Put it before ``A.Normalize``: the camera sees 8-bit or ``[0, 1]`` pixels.

    Randomness follows albumentations' own: whether a call applies is drawn from ``self.py_random`` (probability
    ``p``), and the degradation's values (noise, ...) come from a ``torch.Generator`` seeded with one integer drawn
    from ``self.random_generator``. So ``A.Compose([...], seed=s)`` gives the same bytes for the same sequence of
    calls, ``ReplayCompose`` replays a call exactly (its params hold that integer, ``"seed"``), and the images of
    one ``images`` call each get their own noise. The work is :class:`camdegrade.CameraDegrade`'s, on the CPU,
    without autograd.

    The transform pickles into DataLoader workers. As with every albumentations transform, a seeded ``Compose``
    copied into several workers repeats the same random sequence in each: re-seed it per worker (see
    ``docs/integrations.md``), or use :class:`camdegrade.DegradedDataset`, whose randomness follows the item, not
    the worker.

    Args:
        profile: a built-in profile name, a ``.safetensors`` path, or a :class:`~camdegrade.CameraProfile`. Only
            names and paths can be written by ``A.to_dict`` (save a profile object with ``profile.save(path)``).
        precision: the network's arithmetic, as for :class:`~camdegrade.CameraDegrade` (``"auto"``, ``"float32"``
            or ``"bfloat16"``).
        p: probability that a call degrades its image(s); 1 by default, like ``CameraDegrade``.

    Examples:
        >>> import albumentations as A
        >>> from camdegrade.integrations.albumentations import AlbumentationsCameraDegrade
        >>> pipeline = A.Compose([A.HorizontalFlip(p=0.5), AlbumentationsCameraDegrade("city100-iphonex")], seed=0)
        >>> image = np.zeros((30, 40, 3), dtype=np.uint8)
        >>> out = pipeline(image=image)["image"]
        >>> out.shape, out.dtype
        ((30, 40, 3), dtype('uint8'))
    """

    def __init__(
        self, profile: CameraProfile | str | os.PathLike[str], precision: Precision = "auto", p: float = 1.0
    ) -> None:
        super().__init__(p=check_probability(p))
        self.profile = os.fspath(profile) if isinstance(profile, os.PathLike) else profile
        self.precision = precision
        self.degrade = CameraDegrade(self.profile, precision=precision)  # validates profile and precision

    def get_params(self) -> dict[str, Any]:
        """Draw the call's only random value: the seed of the torch generator the degradation draws from."""
        return {"seed": int(self.random_generator.integers(_SEED_BOUND))}

    def apply(self, img: np.ndarray, seed: int, **params: Any) -> np.ndarray:
        return self._degrade(img, seed, batched=False)

    def apply_to_images(self, images: np.ndarray, seed: int, **params: Any) -> np.ndarray:
        # One generator for the whole stack, so each image gets its own noise (the base class would call
        # ``apply`` per image with the same seed, repeating the noise).
        return self._degrade(images, seed, batched=True)

    def _degrade(self, array: np.ndarray, seed: int, *, batched: bool) -> np.ndarray:
        _check_hwc(array, batched)
        # torch refuses to share read-only memory; the copy is never written (CameraDegrade returns a new tensor).
        source = array if array.flags.writeable else array.copy()
        frames = torch.from_numpy(source).movedim(-1, -3).contiguous()
        degraded = self.degrade.degrade_with(frames, generator=torch.Generator().manual_seed(seed), p=1.0)
        return np.ascontiguousarray(degraded.movedim(-3, -1).numpy())

    def get_transform_init_args(self) -> dict[str, Any]:
        profile = self.profile if isinstance(self.profile, str) else f"<CameraProfile {self.profile.name!r}>"
        return {"profile": profile, "precision": self.precision}

    def to_dict_private(self) -> dict[str, Any]:
        if not isinstance(self.profile, str):
            # albumentations' convention for transforms it cannot write (A.to_dict(..., "warn") skips them).
            raise NotImplementedError(
                f"{type(self).__name__} can only serialise a profile given by name or path, got a CameraProfile "
                f"object ({self.profile.name!r}); save it with profile.save('camera.safetensors') and pass the path"
            )
        return super().to_dict_private()


def _check_hwc(array: Any, batched: bool) -> None:
    expected = "(N, H, W, 3)" if batched else "(H, W, 3)"
    if not isinstance(array, np.ndarray) or array.ndim != (4 if batched else 3) or array.shape[-1] != 3:
        got = f"shape {array.shape}" if isinstance(array, np.ndarray) else type(array).__name__
        raise ValueError(
            f"AlbumentationsCameraDegrade expects RGB numpy images shaped {expected}, got {got}; "
            "convert grayscale or RGBA images to 3-channel RGB first"
        )
    if array.dtype != np.uint8 and not np.issubdtype(array.dtype, np.floating):
        raise TypeError(f"AlbumentationsCameraDegrade supports uint8 and float images, got dtype={array.dtype}")
