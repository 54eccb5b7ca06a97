"""``CameraDegrade``: a torchvision v2 transform that applies a camera profile."""

from __future__ import annotations

import copy
import math
import os
import threading
from typing import Any

import PIL.Image
import torch
from torch import Tensor
from torch.utils._pytree import tree_flatten, tree_unflatten
from torch.utils.data import get_worker_info
from torchvision import tv_tensors
from torchvision.transforms.v2 import Transform
from torchvision.transforms.v2 import functional as TF

from camdegrade._fingerprint import module_tensors, tensors_fingerprint
from camdegrade._pixels import bytes_to_unit, unit_to_bytes
from camdegrade.inference import Precision, resolve_precision
from camdegrade.profile import CameraProfile, EffectParams, load_profile

_MAIN_PROCESS = -1
_FLOAT_DTYPES = (torch.float16, torch.bfloat16, torch.float32, torch.float64)


def _is_plain_tensor(inpt: Any) -> bool:
    return isinstance(inpt, Tensor) and not isinstance(inpt, tv_tensors.TVTensor)


class CameraDegrade(Transform):
    """Make images look as if the profile's camera had captured them.

    A drop-in torchvision v2 transform: put it in a ``v2.Compose`` before normalisation. Images are PIL RGB
    (returned as PIL), uint8 or float tensors ``[..., 3, H, W]`` (same dtype back; float in ``[0, 1]``), or
    ``tv_tensors.Image`` / ``tv_tensors.Video`` (same type back). Boxes, masks, labels and anything else in a
    sample pass through as the same objects, and dict/list/tuple samples keep their structure. Plain tensors follow
    torchvision's rule: when a sample holds no explicit image, only the first plain tensor is treated as one.

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

    _transformed_types = (tv_tensors.Image, tv_tensors.Video, PIL.Image.Image, _is_plain_tensor)

    def __init__(
        self,
        profile: CameraProfile | str | os.PathLike[str],
        p: float = 1.0,
        seed: int | None = None,
        precision: Precision = "auto",
    ) -> None:
        super().__init__()
        if isinstance(profile, (str, os.PathLike)):
            profile = load_profile(profile)
        if not isinstance(profile, CameraProfile):
            raise TypeError(f"profile must be a CameraProfile, a profile name or a path, got {type(profile).__name__}")
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int)):
            raise TypeError(f"seed must be an int or None, got seed={seed!r}")
        self.profile = profile.eval()
        self.p = check_probability(p)
        self.seed = seed
        resolve_precision(precision, torch.device("cpu"))  # validates the name
        self.precision = precision
        self._generator = None if seed is None else torch.Generator().manual_seed(seed)
        self._generator_worker = _MAIN_PROCESS
        self._device_profiles: dict[torch.device, tuple[tuple[int, ...], CameraProfile]] = {}
        self._lock = threading.Lock()

    def __getstate__(self) -> dict[str, Any]:
        state = super().__getstate__()
        state["_device_profiles"] = {}
        state.pop("_lock", None)
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        super().__setstate__(state)
        self._lock = threading.Lock()

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
        effect's values. The draws are the same whatever ``p`` is, so ``p`` only changes which samples change."""
        p = self.p if p is None else check_probability(p)
        if not flat_inputs:
            return {"apply": torch.zeros(0, dtype=torch.bool), "effects": [], "frames": (0, 3, 0, 0)}
        first = flat_inputs[0]
        frames = _frames_shape(first)
        samples = _decision_count(first)
        decisions = torch.rand(samples, generator=generator) < p
        frames_per_sample = frames[0] // samples if samples else 0
        return {
            "apply": decisions if frames_per_sample == 1 else decisions.repeat_interleave(frames_per_sample),
            "effects": self.profile.make_params(frames, generator),
            "frames": frames,
        }

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
        if isinstance(inpt, PIL.Image.Image):
            return self._transform_pil(inpt, params)
        return self._transform_tensor(inpt, params)

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
        if frames[0] == 0 or not bool(apply.any()):
            return image
        plain = image.as_subclass(Tensor)
        batch = plain.reshape(frames)
        degraded = self._degrade_frames(batch, apply, params["effects"])
        out = degraded.reshape(plain.shape)
        return tv_tensors.wrap(out, like=image) if isinstance(image, tv_tensors.TVTensor) else out

    def _degrade_frames(self, batch: Tensor, apply: Tensor, effect_params: EffectParams) -> Tensor:
        profile = self.profile_on(batch.device)
        if bool(apply.all()):
            return degrade_frames(profile, batch, _params_on(effect_params, batch.device), self.precision)
        selected = apply.nonzero().squeeze(1)
        subset_params = [{key: value[selected] for key, value in stage.items()} for stage in effect_params]
        selected = selected.to(batch.device)
        result = degrade_frames(profile, batch[selected], _params_on(subset_params, batch.device), self.precision)
        out = batch.clone()
        out[selected] = result
        return out

    def profile_on(self, device: torch.device) -> CameraProfile:
        """The profile as float32 on ``device``: the profile itself when it already is, else a cached copy.

        A copy is rebuilt whenever the profile's tensors change (``load_state_dict``, ``.to()``, in-place edits).
        """
        if _is_float32_on(self.profile, device):
            return self.profile
        fingerprint = tensors_fingerprint(module_tensors(self.profile))
        with self._lock:
            cached = self._device_profiles.get(device)
            if cached is None or cached[0] != fingerprint:
                cached = (fingerprint, copy.deepcopy(self.profile).to(device=device, dtype=torch.float32))
                self._device_profiles[device] = cached
            return cached[1]

    def extra_repr(self) -> str:
        return f"profile={self.profile.name!r}, p={self.p}, seed={self.seed}, precision={self.precision!r}"


#: On the CPU, frames are degraded in chunks of about this many pixels: a chunk's working tensors then stay in
#: the CPU's L2 cache, where the memory-bound elementwise stages run several times faster than on a whole batch.
CHUNK_PIXELS = 1 << 17


def degrade_frames(profile: CameraProfile, frames: Tensor, params: EffectParams, precision: Precision) -> Tensor:
    """``profile`` applied without autograd to ``frames`` ``(N, 3, H, W)`` (uint8 or float in [0, 1]), returned
    in their dtype; on the CPU in chunks of :data:`CHUNK_PIXELS` (each param is sliced along its batch dim)."""
    count, _, height, width = frames.shape
    step = count if frames.device.type != "cpu" else max(1, CHUNK_PIXELS // max(1, height * width))
    if step >= count:
        return _degrade_chunk(profile, frames, params, precision)
    out = torch.empty_like(frames)
    for start in range(0, count, step):
        chunk = slice(start, min(start + step, count))
        chunk_params = [{key: value[chunk] for key, value in stage.items()} for stage in params]
        out[chunk] = _degrade_chunk(profile, frames[chunk], chunk_params, precision)
    return out


def _degrade_chunk(profile: CameraProfile, frames: Tensor, params: EffectParams, precision: Precision) -> Tensor:
    with torch.no_grad():
        unit = frames if frames.dtype == torch.uint8 else to_unit_float(frames)  # the profile reads uint8 itself
        degraded = profile(unit, params, precision=precision)
        return from_unit_float(degraded, frames.dtype, overwrite=True)  # the profile returns a new tensor


def _params_on(params: EffectParams, device: torch.device) -> EffectParams:
    return [{key: value.to(device) for key, value in stage.items()} for stage in params]


def check_probability(p: Any) -> float:
    if isinstance(p, bool) or not isinstance(p, (int, float)) or not 0.0 <= p <= 1.0:
        raise ValueError(f"p must be a probability from 0 to 1, got p={p!r}")
    return float(p)


def _frames_shape(inpt: Any) -> tuple[int, int, int, int]:
    """``(N, 3, H, W)``: the input seen as a flat batch of frames."""
    if isinstance(inpt, PIL.Image.Image):
        width, height = inpt.size
        return (1, 3, height, width)
    check_image_tensor(inpt)
    *leading, channels, height, width = inpt.shape
    return (math.prod(leading), channels, height, width)


def _decision_count(inpt: Any) -> int:
    """How many independent degrade/keep decisions a sample takes: one per image, one per video."""
    if isinstance(inpt, PIL.Image.Image):
        return 1
    leading = inpt.shape[:-3]
    if isinstance(inpt, tv_tensors.Video) and leading:
        leading = leading[:-1]
    return math.prod(leading)


def check_image_tensor(image: Tensor) -> None:
    if image.ndim < 3 or image.shape[-3] != 3:
        raise ValueError(
            f"CameraDegrade() expects RGB images shaped [..., 3, H, W], got shape {tuple(image.shape)}; "
            "convert grayscale or RGBA images to 3-channel RGB first"
        )
    if image.dtype != torch.uint8 and image.dtype not in _FLOAT_DTYPES:
        raise TypeError(f"CameraDegrade() supports uint8 and floating-point images, got dtype={image.dtype}")
    if image.dtype != torch.uint8 and image.numel() and not bool(torch.isfinite(image).all()):
        raise ValueError("CameraDegrade() got an image containing NaN or infinite values")


def to_unit_float(image: Tensor) -> Tensor:
    if image.dtype == torch.uint8:
        return bytes_to_unit(image)
    return image.float().clamp(0.0, 1.0)


def from_unit_float(image: Tensor, dtype: torch.dtype, *, overwrite: bool = False) -> Tensor:
    """``image`` in [0, 1] as ``dtype`` (uint8: scaled and rounded); ``overwrite`` lets it reuse ``image``."""
    if dtype == torch.uint8:
        return unit_to_bytes(image, overwrite=overwrite)
    return image.to(dtype)


def _is_float32_on(module: torch.nn.Module, device: torch.device) -> bool:
    return all(
        t.device == device and (t.dtype == torch.float32 or not t.is_floating_point()) for t in module_tensors(module)
    )


def _worker_seed(seed: int, worker_id: int) -> int:
    return (seed * 1_000_003 + worker_id + 1) % (2**63)
