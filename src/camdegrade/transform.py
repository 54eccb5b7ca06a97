"""``CameraDegrade``: a torchvision v2 transform that applies a camera profile."""

from __future__ import annotations

import math
import os
import warnings
from typing import Any

import numpy as np
import PIL.Image
import torch
from torch import Tensor
from torch.utils._pytree import tree_flatten, tree_unflatten
from torch.utils.data import get_worker_info
from torchvision import tv_tensors
from torchvision.transforms.v2 import Transform
from torchvision.transforms.v2 import functional as TF

from camdegrade._support.checks import check_probability, check_seed
from camdegrade._support.seeds import derive_seed
from camdegrade.engine import (
    DeviceCopies,
    check_image_shape,
    check_image_tensor,
    degrade_selected,
    one_warp,
    warp_boxes,
    warp_keypoints,
    warp_mask,
)
from camdegrade.errors import PlainTensorsWarning
from camdegrade.network.inference import Precision, resolve_precision
from camdegrade.profile import CameraProfile, EffectParams, as_profile

__all__ = ["TARGETS", "CameraDegrade"]

_MAIN_PROCESS = -1
#: The targets that move with the image when a profile moves pixels (distortion, misalignment).
TARGETS = (tv_tensors.Mask, tv_tensors.BoundingBoxes, tv_tensors.KeyPoints)
#: Box formats whose boxes stay axis-aligned, so a warped box is the box enclosing the warped outline.
_AXIS_ALIGNED = (
    tv_tensors.BoundingBoxFormat.XYXY,
    tv_tensors.BoundingBoxFormat.XYWH,
    tv_tensors.BoundingBoxFormat.CXCYWH,
)
_NUMPY_DTYPES = (np.uint8, np.float16, np.float32, np.float64)


def _is_plain_tensor(inpt: Any) -> bool:
    return isinstance(inpt, Tensor) and not isinstance(inpt, tv_tensors.TVTensor)


def _is_numpy_image(inpt: Any) -> bool:
    """A numpy array shaped ``(..., H, W, 3)``: an RGB image as albumentations and Hugging Face hold them."""
    return isinstance(inpt, np.ndarray) and inpt.ndim >= 3 and inpt.shape[-1] == 3


def _is_image_shaped(inpt: Any) -> bool:
    return _is_plain_tensor(inpt) and inpt.ndim >= 3 and inpt.shape[-3] == 3


class CameraDegrade(Transform):
    """Make images look as if the profile's camera had captured them.

    A drop-in torchvision v2 transform: put it in a ``v2.Compose`` before normalisation. Images are PIL RGB
    (returned as PIL), uint8 or float tensors ``[..., 3, H, W]`` (same dtype back; float in ``[0, 1]``), or
    ``tv_tensors.Image`` / ``tv_tensors.Video`` (same type back), or numpy arrays ``(..., H, W, 3)`` as
    albumentations and Hugging Face datasets hold them (uint8, or float in ``[0, 1]``; a new numpy array of the
    same dtype back). Labels and anything else in a sample pass through as the same objects, and dict/list/tuple
    samples keep their structure. A sample with no image in it is refused with a ``TypeError``.

    Targets travel with the image: when the profile moves pixels (distortion, misalignment), ``tv_tensors.Mask``
    (nearest value, 0 where the frame had no content), ``tv_tensors.BoundingBoxes`` (the box enclosing the moved
    outline, clamped as the boxes' ``clamping_mode`` says) and ``tv_tensors.KeyPoints`` (not clamped) are moved by
    the same warp in the same call; rotated box formats are refused. Otherwise, and when a sample is not degraded,
    they come back as the same objects.

    Plain tensors follow torchvision's rule: when a sample holds no explicit image (PIL, ``tv_tensors.Image`` or
    ``Video``, numpy), only the first plain tensor is treated as one, so ``CameraDegrade()([a, b])`` degrades ``a``
    only (a :class:`PlainTensorsWarning` says so, once); wrap each in ``tv_tensors.Image`` to degrade both.

    All randomness of a call is drawn in :meth:`make_params` (whether each sample is degraded, with probability
    ``p``, and every stochastic effect's values), so ``t.transform(x, params)`` replays a call exactly. The work
    runs without autograd on the input's device; the profile is copied to each device once and cached.

    Args:
        profile: a :class:`CameraProfile`, a built-in profile name (see :func:`list_profiles`) or a path to a
            ``.safetensors`` profile.
        p: probability that each sample (each image of a batch; each video, all frames alike) is degraded.
        seed: seeds this transform's own ``torch.Generator``, so the sequence of calls is reproducible.
            ``None`` draws from torch's global RNG, which DataLoader seeds differently in every worker. A seeded
            transform copied into DataLoader workers re-seeds once per worker from ``(seed, worker id)``.
        precision: the network's arithmetic: ``"auto"`` (default) uses bfloat16 where the device computes it
            natively (modern x86 CPUs with AVX-512 BF16/AMX, recent GPUs) — 8-bit outputs stay within one level of
            float32 on ≥ 99.9 % of pixels — else float32; ``"float32"`` is the reference.

    Examples:
        >>> degrade = CameraDegrade("city100-iphonex", seed=0)
        >>> image = torch.zeros(3, 30, 40, dtype=torch.uint8)
        >>> degrade(image).shape, degrade(image).dtype
        (torch.Size([3, 30, 40]), torch.uint8)
    """

    _transformed_types = (
        tv_tensors.Image,
        tv_tensors.Video,
        PIL.Image.Image,
        _is_plain_tensor,
        _is_numpy_image,
        *TARGETS,
    )

    def __init__(
        self,
        profile: CameraProfile | str | os.PathLike[str],
        p: float = 1.0,
        seed: int | None = None,
        precision: Precision = "auto",
    ) -> None:
        super().__init__()
        profile = as_profile(profile)
        if seed is not None:
            check_seed(seed)
        self.profile = profile.eval()
        self.p = check_probability(p)
        self.seed = seed
        resolve_precision(precision, torch.device("cpu"))  # validates the name
        self.precision = precision
        self._generator = None if seed is None else torch.Generator().manual_seed(seed)
        self._generator_worker = _MAIN_PROCESS
        self._device_copies = DeviceCopies()
        self._warned_plain_tensors = False

    # torch.compile runs the transform as it is, eagerly (same bytes as without it, at once, and a compiled model
    # around it still compiles): it draws from a torch.Generator, encodes through libjpeg and branches on the input's
    # type, none of which a graph holds (Inductor failed on it after a minute). torchvision's own forward is kept.
    forward = torch.compiler.disable(Transform.forward)

    def check_inputs(self, flat_inputs: list[Any]) -> None:
        """Refuse ``torch.jit.trace`` at once: a trace would record this call's random draws and its type checks as
        constants (``torch.jit.script`` is refused by torchvision's ``Transform``)."""
        if torch.jit.is_tracing():
            raise RuntimeError(
                "CameraDegrade() cannot be traced with torch.jit.trace: a trace would replay one call's random draws "
                "and libjpeg's output as constants; call the transform eagerly (under torch.compile it runs eagerly "
                "by itself), or trace only the model after it"
            )

    def _needs_transform_list(self, flat_inputs: list[Any]) -> list[bool]:
        # torchvision's rule for plain tensors, with numpy images counted as explicit images (as PIL images are),
        # and a warning (once) when it leaves image-shaped plain tensors undegraded beside the first.
        needs = super()._needs_transform_list(flat_inputs)
        if len(flat_inputs) == 1:  # a bare image: nothing beside it
            return needs
        skipped, degraded_plain = 0, False
        for inpt, needed in zip(flat_inputs, needs, strict=True):
            if isinstance(inpt, np.ndarray) and needed:  # a numpy image: plain tensors beside it are no images
                return [wanted and not _is_plain_tensor(item) for item, wanted in zip(flat_inputs, needs, strict=True)]
            if _is_plain_tensor(inpt):
                degraded_plain |= needed
                skipped += not needed and _is_image_shaped(inpt)
        if skipped and degraded_plain and not self._warned_plain_tensors:
            self._warned_plain_tensors = True
            warnings.warn(
                f"CameraDegrade() degrades only the first of {skipped + 1} plain image-shaped tensors in a sample "
                "(torchvision's rule for plain tensors); wrap each image in tv_tensors.Image to degrade them all",
                PlainTensorsWarning,
                stacklevel=3,
            )
        return needs

    def make_params(self, flat_inputs: list[Any]) -> dict[str, Any]:
        """Draw this call's randomness from the transform's own generator (see :meth:`draw_params`)."""
        return self.draw_params(flat_inputs, self._process_generator())

    def _process_generator(self) -> torch.Generator | None:
        """The seeded generator, re-seeded once per DataLoader worker from ``(seed, worker id)``.

        Every worker receives a copy of the transform; without this, all of them would replay the same random
        sequence and items loaded by different workers would share their noise.
        """
        if self.seed is None:
            return None
        worker = get_worker_info()
        worker_id = _MAIN_PROCESS if worker is None else worker.id
        if worker_id != self._generator_worker:
            self._generator = torch.Generator().manual_seed(_worker_seed(self.seed, worker_id))
            self._generator_worker = worker_id
        return self._generator

    def draw_params(
        self, flat_inputs: list[Any], generator: torch.Generator | None, p: float | None = None
    ) -> dict[str, Any]:
        """Draw a call's randomness from ``generator`` for the first image in ``flat_inputs`` (the others must share
        its shape): whether each sample is degraded (probability ``p``, default ``self.p``) and every stochastic
        effect's values. The draws are the same whatever ``p`` is, so ``p`` only changes which samples change.

        When ``flat_inputs`` also holds targets (masks, boxes, keypoints), ``"warp"`` holds the one warp that moves
        them (see :func:`camdegrade.engine.one_warp`); a ``TypeError`` when it holds no image.
        """
        p = self.p if p is None else check_probability(p)
        images = [inpt for inpt in flat_inputs if not isinstance(inpt, TARGETS)]
        if not images:
            raise TypeError(
                "CameraDegrade() found no image in the sample: it degrades PIL RGB images, tensors [..., 3, H, W], "
                "tv_tensors.Image/Video and numpy arrays (..., H, W, 3); convert grayscale or channels-first numpy "
                "images first"
            )
        first = images[0]
        frames = _frames_shape(first)
        samples = _decision_count(first)
        decisions = torch.rand(samples, generator=generator) < p
        frames_per_sample = frames[0] // samples if samples else 0
        apply = decisions if frames_per_sample == 1 else decisions.repeat_interleave(frames_per_sample)
        effects = self.profile.make_params(frames, generator)
        has_targets = len(images) < len(flat_inputs)
        warp = one_warp(self.profile, effects, apply) if has_targets else None
        return {"apply": apply, "effects": effects, "frames": frames, "warp": warp}

    def degrade_with(self, *inputs: Any, generator: torch.Generator | None, p: float | None = None) -> Any:
        """Like calling the transform, but drawing from ``generator`` (and with probability ``p`` if given).

        Used where the caller owns the randomness, e.g. a dataset seeding one generator per (item, epoch) so
        results do not depend on the worker that loads the item.
        """
        flat_inputs, spec = tree_flatten(inputs if len(inputs) > 1 else inputs[0])
        needs_transform = self._needs_transform_list(flat_inputs)
        params = self.draw_params([x for x, needed in zip(flat_inputs, needs_transform) if needed], generator, p)
        flat_outputs = [self.transform(x, params) if needed else x for x, needed in zip(flat_inputs, needs_transform)]
        return tree_unflatten(flat_outputs, spec)

    def transform(self, inpt: Any, params: dict[str, Any]) -> Any:
        if isinstance(inpt, TARGETS):
            return self._move_target(inpt, params)
        if isinstance(inpt, PIL.Image.Image):
            return self._transform_pil(inpt, params)
        if isinstance(inpt, np.ndarray):
            return self._transform_numpy(inpt, params)
        return self._transform_tensor(inpt, params)

    def _transform_numpy(self, array: np.ndarray, params: dict[str, Any]) -> np.ndarray:
        _check_numpy_image(array)
        if not bool(params["apply"].any()):
            return array
        # torch shares only writeable, native-order, positively strided memory; this copy is never written.
        usable = array.flags.writeable and array.dtype.isnative and all(step >= 0 for step in array.strides)
        source = torch.from_numpy(array if usable else np.array(array, dtype=array.dtype.newbyteorder("=")))
        degraded = self._transform_tensor(source.movedim(-1, -3), params)
        return np.ascontiguousarray(degraded.movedim(-3, -1).numpy())

    def _move_target(self, target: Any, params: dict[str, Any]) -> Any:
        """``target`` moved by the call's warp (``params["warp"]``, one frame's params), or itself if none."""
        warp = params.get("warp")
        if warp is None:  # nothing moves, or params drawn for the image alone (a replay): find the warp now
            warp = one_warp(self.profile, params["effects"], params["apply"])
        if warp is None:
            return target
        size = tuple(params["frames"][-2:])
        plain = target.as_subclass(Tensor)
        if isinstance(target, tv_tensors.Mask):
            _check_size("a tv_tensors.Mask", tuple(target.shape[-2:]), size)
            return tv_tensors.wrap(warp_mask(self.profile, warp, plain), like=target)
        _check_size(f"a tv_tensors.{type(target).__name__}", tuple(target.canvas_size), size)
        if isinstance(target, tv_tensors.KeyPoints):
            moved = warp_keypoints(self.profile, warp, plain, size)
            return tv_tensors.wrap(_as_dtype(moved, target.dtype), like=target)
        return self._move_boxes(target, warp, size)

    def _move_boxes(self, boxes: tv_tensors.BoundingBoxes, warp: EffectParams, size: tuple[int, int]) -> Any:
        if boxes.format not in _AXIS_ALIGNED:
            raise ValueError(
                f"CameraDegrade() cannot move rotated boxes (format {boxes.format.name}) exactly through profile "
                f"{self.profile.name!r}'s warp; give them as axis-aligned boxes (XYXY, XYWH, CXCYWH) or as masks"
            )
        xyxy = TF.convert_bounding_box_format(boxes, new_format=tv_tensors.BoundingBoxFormat.XYXY)
        moved = warp_boxes(self.profile, warp, xyxy.as_subclass(Tensor).reshape(-1, 4), size).reshape(xyxy.shape)
        moved = tv_tensors.wrap(moved.to(xyxy.device), like=xyxy)
        out = TF.convert_bounding_box_format(TF.clamp_bounding_boxes(moved), new_format=boxes.format)
        return tv_tensors.wrap(_as_dtype(out.as_subclass(Tensor), boxes.dtype), like=boxes)

    def _transform_pil(self, image: PIL.Image.Image, params: dict[str, Any]) -> PIL.Image.Image:
        if image.mode != "RGB":
            raise ValueError(
                f"CameraDegrade() does not support PIL images in mode {image.mode!r}; convert to 'RGB' first "
                "(e.g. image.convert('RGB'))"
            )
        return TF.to_pil_image(self._transform_tensor(TF.pil_to_tensor(image), params))

    def _transform_tensor(self, image: Tensor, params: dict[str, Any]) -> Tensor:
        check_image_tensor(image)
        frames = _frames_shape(image)
        if frames != tuple(params["frames"]):
            raise ValueError(
                f"all images in one sample must share a shape: params were drawn for {tuple(params['frames'])} "
                f"frames (N, C, H, W), got an image with {frames}"
            )
        apply = params["apply"]
        if image.numel() == 0 or not bool(apply.any()):  # empty in, empty out
            return image
        plain = image.as_subclass(Tensor)
        batch = plain.reshape(frames)
        degraded = self._degrade_frames(batch, apply, params["effects"])
        out = degraded.reshape(plain.shape)
        return tv_tensors.wrap(out, like=image) if isinstance(image, tv_tensors.TVTensor) else out

    def _degrade_frames(self, batch: Tensor, apply: Tensor, effect_params: EffectParams) -> Tensor:
        return degrade_selected(self.profile_on(batch.device), batch, apply, effect_params, self.precision)

    def profile_on(self, device: torch.device) -> CameraProfile:
        """The profile as float32 on ``device``: the profile itself when it already is, else a cached copy.

        A copy is rebuilt whenever the profile's tensors change (``load_state_dict``, ``.to()``, in-place edits).
        """
        return self._device_copies.on(self.profile, device)

    def extra_repr(self) -> str:
        return f"profile={self.profile.name!r}, p={self.p}, seed={self.seed}, precision={self.precision!r}"


def _check_size(what: str, got: tuple[int, ...], size: tuple[int, ...]) -> None:
    if got != size:
        raise ValueError(
            f"CameraDegrade() moves targets with their image, so {what} must match the image's size (H, W) = "
            f"{size}, got {got}"
        )


def _as_dtype(values: Tensor, dtype: torch.dtype) -> Tensor:
    """Moved coordinates in a target's dtype: integers are rounded, not truncated."""
    return values.to(dtype) if dtype.is_floating_point else values.round().to(dtype)


def _check_numpy_image(array: np.ndarray) -> None:
    if array.dtype.type not in _NUMPY_DTYPES:
        raise TypeError(
            "CameraDegrade() supports numpy images of dtype uint8, float16, float32 or float64, "
            f"got dtype={array.dtype}"
        )


def _frames_shape(inpt: Any) -> tuple[int, int, int, int]:
    """``(N, 3, H, W)``: the input seen as a flat batch of frames."""
    if isinstance(inpt, PIL.Image.Image):
        width, height = inpt.size
        return (1, 3, height, width)
    if isinstance(inpt, np.ndarray):
        _check_numpy_image(inpt)
        *leading, height, width, channels = inpt.shape
        return (math.prod(leading), channels, height, width)
    check_image_shape(inpt)
    *leading, channels, height, width = inpt.shape
    return (math.prod(leading), channels, height, width)


def _decision_count(inpt: Any) -> int:
    """How many independent degrade/keep decisions a sample takes: one per image, one per video."""
    if isinstance(inpt, PIL.Image.Image):
        return 1
    if isinstance(inpt, np.ndarray):
        return math.prod(inpt.shape[:-3])
    leading = inpt.shape[:-3]
    if isinstance(inpt, tv_tensors.Video) and leading:
        leading = leading[:-1]
    return math.prod(leading)


def _worker_seed(seed: int, worker_id: int) -> int:
    return derive_seed(seed, "dataloader-worker", worker_id)
