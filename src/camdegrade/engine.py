"""Frames through a profile: input checks, 8-bit handling, CPU chunking and per-device float32 copies; and the
targets of a frame (masks, boxes, keypoints) through the same warp.

The engine knows tensors ``(N, 3, H, W)`` and profiles, nothing of PIL, tv_tensors or sample structures (that is
:mod:`camdegrade.transform`), so the dataset and batch modules use it without importing torchvision.
"""

from __future__ import annotations

import copy
import threading

import torch
from torch import Tensor

from camdegrade._support.fingerprint import module_tensors, tensors_fingerprint
from camdegrade._support.pixels import NOT_FINITE, SCALE_HINT, as_unit, off_unit_scale, unit_to_bytes
from camdegrade.effects.chain import chain_moved_points, chain_source_points, moves_pixels
from camdegrade.functional.optics.geometry import centered_coordinates, remap_labels
from camdegrade.network.inference import Precision
from camdegrade.profile import CameraProfile, EffectParams

__all__ = [
    "BOX_EDGE_POINTS",
    "CHUNK_PIXELS",
    "FLOAT_DTYPES",
    "DeviceCopies",
    "check_image_shape",
    "check_image_tensor",
    "degrade_frames",
    "degrade_selected",
    "one_warp",
    "params_on",
    "select_params",
    "warp_boxes",
    "warp_keypoints",
    "warp_mask",
    "warp_points",
]

#: On the CPU, frames are degraded in chunks of about this many pixels: a chunk's working tensors then stay in
#: the CPU's L2 cache, where the memory-bound elementwise stages run several times faster than on a whole batch.
CHUNK_PIXELS = 1 << 17
FLOAT_DTYPES = (torch.float16, torch.bfloat16, torch.float32, torch.float64)


def check_image_shape(image: Tensor, who: str = "CameraDegrade()") -> None:
    """Raise a clear error unless ``image`` is a dense ``[..., 3, H, W]`` uint8 or floating-point tensor holding
    data (not on the meta device). Reads no values."""
    if image.is_nested:
        raise TypeError(
            f"{who} supports dense tensors, got a nested tensor; pass its images one by one (nested.unbind())"
        )
    if image.layout != torch.strided:
        raise TypeError(f"{who} supports dense tensors, got layout={image.layout}; convert it with .to_dense()")
    if image.is_meta:
        raise TypeError(f"{who} got a tensor on the 'meta' device, which holds no values; use a device such as 'cpu'")
    if image.ndim < 3 or image.shape[-3] != 3:
        raise ValueError(
            f"{who} expects RGB images shaped [..., 3, H, W], got shape {tuple(image.shape)}; "
            "convert grayscale or RGBA images to 3-channel RGB first"
        )
    if image.dtype != torch.uint8 and image.dtype not in FLOAT_DTYPES:
        raise TypeError(f"{who} supports uint8 and floating-point images, got dtype={image.dtype}")


def check_image_tensor(image: Tensor, who: str = "CameraDegrade()") -> None:
    """:func:`check_image_shape`, and for floats: finite values within 0.1 of [0, 1] (one ``aminmax`` pass,
    :func:`camdegrade._support.pixels.off_unit_scale`)."""
    check_image_shape(image, who)
    if image.dtype == torch.uint8 or image.numel() == 0:
        return
    problem = off_unit_scale(image)
    if problem == NOT_FINITE:
        raise ValueError(f"{who} got an image containing NaN or infinite values")
    if problem is not None:
        raise ValueError(
            f"{who} expects float images in [0, 1], got {problem}; {SCALE_HINT}, and degrade before normalising"
        )


def degrade_frames(profile: CameraProfile, frames: Tensor, params: EffectParams, precision: Precision) -> Tensor:
    """``profile`` applied without autograd to ``frames`` ``(N, 3, H, W)`` (uint8 or float in [0, 1]), returned
    in their dtype; on the CPU in chunks of :data:`CHUNK_PIXELS` (each param is sliced along its batch dim)."""
    count, _, height, width = frames.shape
    if frames.numel() == 0:
        return frames.clone()
    step = count if frames.device.type != "cpu" else max(1, CHUNK_PIXELS // max(1, height * width))
    if step >= count:
        return _degrade_chunk(profile, frames, params, precision)
    out = torch.empty_like(frames)
    for start in range(0, count, step):
        chunk = slice(start, min(start + step, count))
        out[chunk] = _degrade_chunk(profile, frames[chunk], select_params(params, chunk), precision)
    return out


def _degrade_chunk(profile: CameraProfile, frames: Tensor, params: EffectParams, precision: Precision) -> Tensor:
    with torch.no_grad():
        unit = frames if frames.dtype == torch.uint8 else as_unit(frames, clamp=True)  # the profile reads uint8
        degraded = profile(unit, params, precision=precision)
        # The profile returns a new tensor, so the conversion may overwrite it.
        return unit_to_bytes(degraded, overwrite=True) if frames.dtype == torch.uint8 else degraded.to(frames.dtype)


def degrade_selected(
    profile: CameraProfile, frames: Tensor, apply: Tensor, params: EffectParams, precision: Precision
) -> Tensor:
    """``frames`` ``(N, 3, H, W)`` with those where ``apply`` ``(N,)`` is true degraded (``params`` drawn for all
    ``N``, on any device). On the CPU only those frames are computed; elsewhere every frame is and ``torch.where``
    picks, which spares the device a synchronisation."""
    params = params_on(params, frames.device)
    apply = apply.to(frames.device)
    if frames.device.type != "cpu":
        degraded = degrade_frames(profile, frames, params, precision)
        return torch.where(apply.view(-1, 1, 1, 1), degraded, frames)
    if bool(apply.all()):
        return degrade_frames(profile, frames, params, precision)
    selected = apply.nonzero().squeeze(1)
    out = frames.clone()
    out[selected] = degrade_frames(profile, frames[selected], select_params(params, selected), precision)
    return out


def select_params(params: EffectParams, index: slice | Tensor) -> EffectParams:
    """The params of the frames ``index`` selects (every param is indexed along its batch dimension)."""
    return [{key: value[index] for key, value in stage.items()} for stage in params]


def params_on(params: EffectParams, device: torch.device) -> EffectParams:
    return [{key: value.to(device) for key, value in stage.items()} for stage in params]


#: Points per box edge mapped through a warp: the enclosing box of the warped outline is within a small fraction
#: of a pixel of the warped box's (the warps are smooth).
BOX_EDGE_POINTS = 33


def one_warp(
    profile: CameraProfile, params: EffectParams, apply: Tensor, who: str = "CameraDegrade()"
) -> EffectParams | None:
    """The params of the one warp that moves every frame of a call, as a single frame's, for its targets; ``None``
    when nothing moves (the profile moves no pixels, or no frame is degraded). A ``ValueError`` when frames move
    differently (some degraded and some not, or per-frame draws of a moving stage): targets could not follow."""
    if not moves_pixels(profile.effects) or not bool(apply.any()):
        return None
    moving = [stage for effect, stage in zip(profile.effects, params, strict=True) if effect.moves_pixels]
    shared = bool(apply.all()) and all(bool((value == value[:1]).all()) for stage in moving for value in stage.values())
    if not shared:
        raise ValueError(
            f"{who} cannot move targets (masks, boxes, keypoints) with {len(apply)} frames that profile "
            f"{profile.name!r} moves differently (each is degraded or not, or draws its own shift); pass one image "
            "per sample with its targets"
        )
    return select_params(params, slice(0, 1))


def warp_mask(profile: CameraProfile, params: EffectParams, mask: Tensor) -> Tensor:
    """``mask`` ``(..., H, W)`` (class ids, instance ids or booleans) moved by the profile's warp with ``params``
    (one frame's): each output pixel takes the nearest value where the warp reads the image from, 0 outside."""
    height, width = mask.shape[-2:]
    x, y = centered_coordinates(height, width, torch.float64, mask.device)
    x, y = chain_source_points(profile.effects, params, x.reshape(1, -1), y.reshape(1, -1), (height, width))
    return remap_labels(mask, x.reshape(height, width), y.reshape(height, width))


def warp_points(profile: CameraProfile, params: EffectParams, points: Tensor, size: tuple[int, int]) -> Tensor:
    """Points ``(..., 2)`` as ``(x, y)`` in pixels from the top-left corner of a ``size = (H, W)`` image (pixel
    ``(i, j)`` spans ``[j, j + 1] × [i, i + 1]``) moved where the profile's warp with ``params`` (one frame's) puts
    them, as float64. Points may leave the frame."""
    height, width = size
    flat = points.reshape(1, -1, 2).to(torch.float64)
    x, y = chain_moved_points(profile.effects, params, flat[..., 0] - width / 2, flat[..., 1] - height / 2, size)
    return torch.stack((x + width / 2, y + height / 2), dim=-1).reshape(points.shape)


def warp_keypoints(profile: CameraProfile, params: EffectParams, points: Tensor, size: tuple[int, int]) -> Tensor:
    """:func:`warp_points` for keypoints ``(..., 2)`` in pixel-index coordinates, as torchvision and albumentations
    hold them (pixel ``j``'s centre at ``x = j``: flips map ``x`` to ``W - 1 - x``), as float64."""
    return warp_points(profile, params, points.to(torch.float64) + 0.5, size) - 0.5


def warp_boxes(profile: CameraProfile, params: EffectParams, boxes: Tensor, size: tuple[int, int]) -> Tensor:
    """Boxes ``(K, 4)`` as ``(x0, y0, x1, y1)`` (coordinates as :func:`warp_points`) replaced by the boxes enclosing
    their outlines moved by the warp, as float64, not clamped to the frame."""
    t = torch.linspace(0.0, 1.0, BOX_EDGE_POINTS, dtype=torch.float64, device=boxes.device)
    x0, y0, x1, y1 = (boxes.to(torch.float64)[:, k, None] for k in range(4))
    xs, ys = x0 + t * (x1 - x0), y0 + t * (y1 - y0)
    outline_x = torch.cat((xs, xs, x0.expand_as(ys), x1.expand_as(ys)), dim=1)
    outline_y = torch.cat((y0.expand_as(xs), y1.expand_as(xs), ys, ys), dim=1)
    moved = warp_points(profile, params, torch.stack((outline_x, outline_y), dim=-1), size)
    return torch.cat((moved.amin(dim=1), moved.amax(dim=1)), dim=-1)


class DeviceCopies:
    """A profile as float32 on any device: the profile itself where it already is, else a copy made once per
    device and rebuilt whenever the profile's tensors change (``load_state_dict``, ``.to()``, in-place edits).
    Safe to share between threads; not pickled (copies are rebuilt on first use)."""

    def __init__(self) -> None:
        self._copies: dict[torch.device, tuple[tuple[int, ...], CameraProfile]] = {}
        self._lock = threading.Lock()

    def __getstate__(self) -> dict:
        return {}

    def __setstate__(self, state: dict) -> None:
        self.__init__()

    def on(self, profile: CameraProfile, device: torch.device) -> CameraProfile:
        if _is_float32_on(profile, device):
            return profile
        fingerprint = tensors_fingerprint(module_tensors(profile))
        with self._lock:
            cached = self._copies.get(device)
            if cached is None or cached[0] != fingerprint:
                cached = (fingerprint, copy.deepcopy(profile).to(device=device, dtype=torch.float32))
                self._copies[device] = cached
            return cached[1]


def _is_float32_on(module: torch.nn.Module, device: torch.device) -> bool:
    return all(
        t.device == device and (t.dtype == torch.float32 or not t.is_floating_point()) for t in module_tensors(module)
    )
