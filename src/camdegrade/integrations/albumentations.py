"""``AlbumentationsCameraDegrade``: a camera profile as an albumentations transform (numpy HWC in and out), with
masks, boxes and keypoints moved by the same warp.

Needs albumentations 2 or later (``pip install 'camdegrade[albumentations]'``). Importing this module registers the
transform with albumentations' serialisation, so ``A.from_dict`` can rebuild pipelines that hold it.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

try:
    from albumentations.core.transforms_interface import DualTransform
except ModuleNotFoundError as error:  # pragma: no cover - only without the extra
    raise ModuleNotFoundError(
        "camdegrade.integrations.albumentations needs albumentations>=2: pip install 'camdegrade[albumentations]'"
    ) from error

from camdegrade._support.checks import check_probability
from camdegrade.engine import one_warp, warp_boxes, warp_keypoints, warp_mask
from camdegrade.network.inference import Precision
from camdegrade.profile import CameraProfile, EffectParams
from camdegrade.transform import CameraDegrade

__all__ = ["AlbumentationsCameraDegrade"]

#: Seeds for the torch generator are drawn from ``[0, 2**63)``, a range ``torch.Generator.manual_seed`` accepts.
_SEED_BOUND = 2**63
#: The targets that move with the image when the profile moves pixels.
_MOVED_TARGETS = ("mask", "masks", "mask3d", "masks3d", "bboxes", "keypoints")
#: Columns of albumentations' internal keypoints: x, y, z, angle (radians), scale, then the user's extra columns.
_ANGLE, _SCALE = 3, 4


class AlbumentationsCameraDegrade(DualTransform):
    """Make images look as if the profile's camera had captured them, inside an ``A.Compose`` pipeline.

    Images are numpy arrays ``(H, W, 3)`` (target ``image``) or ``(N, H, W, 3)`` (target ``images``), uint8 or
    float in ``[0, 1]``; they come back with the same shape and dtype, in a new array. Put it before
    ``A.Normalize``: the camera sees 8-bit or ``[0, 1]`` pixels.

    Targets travel with the image, as with :class:`~camdegrade.CameraDegrade`: when the profile moves pixels
    (distortion, misalignment), masks (``mask``, ``masks``, ``mask3d``, ``masks3d``; nearest value, 0 where the
    frame had no content), ``bboxes`` (the box enclosing the moved outline; albumentations' bbox processor then
    clips or drops them as configured) and ``keypoints`` (position; angle and scale by the warp's local rotation
    and stretch) are moved by the same warp in the same call. Otherwise they come back unchanged. With ``images``,
    targets are refused when the images move differently (a profile drawing a shift per image).

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

    @property
    def targets(self) -> dict[str, Callable[..., Any]]:
        # DualTransform's targets, with every kind of mask moved whole by the one warp (DualTransform would run
        # the image's per-slice machinery on 3-D masks).
        return {
            "image": self.apply,
            "images": self.apply_to_images,
            "volume": self.apply_to_volume,
            "volumes": self.apply_to_volumes,
            "mask": self.apply_to_mask,
            "masks": self.apply_to_masks,
            "mask3d": self.apply_to_mask3d,
            "masks3d": self.apply_to_masks3d,
            "bboxes": self.apply_to_bboxes,
            "keypoints": self.apply_to_keypoints,
        }

    def get_params_dependent_on_data(self, params: dict[str, Any], data: dict[str, Any]) -> dict[str, Any]:
        """How many frames the call's draws cover (``images``: one per image); refuses targets that could not
        follow frames moving differently."""
        frames = len(data["images"]) if "images" in data and "image" not in data else 1
        if any(key in data for key in _MOVED_TARGETS):
            self._warp(params["seed"], params["shape"], frames)  # raises when the frames move differently
        return {"frames": frames}

    def _warp(self, seed: int, shape: tuple[int, ...], frames: int) -> EffectParams | None:
        """The one warp of this call's images (drawn from ``seed`` exactly as they are), or ``None``."""
        probe = torch.zeros((), dtype=torch.uint8).expand(frames, 3, *shape[:2])
        drawn = self.degrade.draw_params([probe], torch.Generator().manual_seed(seed), p=1.0)
        return one_warp(self.degrade.profile, drawn["effects"], drawn["apply"], type(self).__name__)

    def apply(self, img: np.ndarray, seed: int, **params: Any) -> np.ndarray:
        return self._degrade(img, seed, batched=False)

    def apply_to_mask(
        self, mask: np.ndarray, seed: int, shape: tuple[int, ...], frames: int = 1, **params: Any
    ) -> np.ndarray:
        return self._move_masks(mask, seed, shape, frames)

    def apply_to_masks(
        self, masks: np.ndarray, seed: int, shape: tuple[int, ...], frames: int = 1, **params: Any
    ) -> np.ndarray:
        return self._move_masks(masks, seed, shape, frames)

    def apply_to_mask3d(
        self, mask3d: np.ndarray, seed: int, shape: tuple[int, ...], frames: int = 1, **params: Any
    ) -> np.ndarray:
        return self._move_masks(mask3d, seed, shape, frames)

    def apply_to_masks3d(
        self, masks3d: np.ndarray, seed: int, shape: tuple[int, ...], frames: int = 1, **params: Any
    ) -> np.ndarray:
        return self._move_masks(masks3d, seed, shape, frames)

    def _move_masks(self, masks: np.ndarray, seed: int, shape: tuple[int, ...], frames: int) -> np.ndarray:
        """Masks whose first two spatial axes are the image's ``(H, W)``: ``(..., H, W)`` or ``(..., H, W, C)``."""
        warp = self._warp(seed, shape, frames)
        if warp is None:
            return masks
        height, width = shape[:2]
        channels_last = masks.shape[-2:] != (height, width)
        if channels_last and masks.shape[-3:-1] != (height, width):
            raise ValueError(
                f"{type(self).__name__} moves masks with their image, so masks must be shaped (..., H, W) or "
                f"(..., H, W, C) with (H, W) = {(height, width)}, got shape {masks.shape}"
            )
        labels = torch.from_numpy(np.ascontiguousarray(masks))
        labels = labels.movedim(-1, 0) if channels_last else labels
        moved = warp_mask(self.degrade.profile, warp, labels)
        return np.ascontiguousarray((moved.movedim(0, -1) if channels_last else moved).numpy())

    def apply_to_bboxes(
        self, bboxes: np.ndarray, seed: int, shape: tuple[int, ...], frames: int = 1, **params: Any
    ) -> np.ndarray:
        """Boxes in albumentations' internal format: ``x_min, y_min, x_max, y_max`` normalised by the image's width
        and height, then extra columns (kept)."""
        warp = self._warp(seed, shape, frames)
        if warp is None or len(bboxes) == 0:
            return bboxes
        height, width = shape[:2]
        scale = np.array([width, height, width, height], dtype=np.float64)
        corners = torch.from_numpy(bboxes[:, :4].astype(np.float64) * scale)
        moved = warp_boxes(self.degrade.profile, warp, corners, (height, width)).numpy() / scale
        out = bboxes.copy()
        out[:, :4] = moved
        return out

    def apply_to_keypoints(
        self, keypoints: np.ndarray, seed: int, shape: tuple[int, ...], frames: int = 1, **params: Any
    ) -> np.ndarray:
        """Keypoints in albumentations' internal format (``x, y, z, angle, scale``, extra columns kept; pixel ``j``'s
        centre at ``x = j``): positions moved, angles turned and scales stretched as the warp does near each."""
        warp = self._warp(seed, shape, frames)
        if warp is None or len(keypoints) == 0:
            return keypoints
        size = tuple(shape[:2])
        points = torch.from_numpy(keypoints[:, :2].astype(np.float64))
        angle = torch.from_numpy(keypoints[:, _ANGLE].astype(np.float64))
        step = 1e-3 * torch.stack((torch.cos(angle), torch.sin(angle)), dim=-1)
        moved = warp_keypoints(self.degrade.profile, warp, torch.stack((points, points + step)), size)
        direction = (moved[1] - moved[0]) / 1e-3
        out = keypoints.copy()
        out[:, :2] = moved[0].numpy()
        out[:, _ANGLE] = (torch.atan2(direction[:, 1], direction[:, 0]) % (2 * torch.pi)).numpy()
        out[:, _SCALE] = keypoints[:, _SCALE] * direction.norm(dim=-1).numpy()
        return out

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
