"""How the network runs at inference: the precision choice, and CPU plans of the modules' arithmetic."""

from __future__ import annotations

import threading
import weakref
from typing import Any, Literal

import torch
import torch.nn.functional as F
from torch import Tensor

from camdegrade._support.fingerprint import module_tensors, tensors_fingerprint
from camdegrade._support.pixels import bytes_to_unit
from camdegrade.network._onednn import (
    FUSED_LINEAR,
    SPARSE_MAX_LIVE,
    SPARSE_MIN_PIXELS,
    conv_relu,
    cpu_native_bfloat16,
    live_linear_relu,
    use_fused_kernels,
)
from camdegrade.network.inference_local_affine import LocalAffineInference
from camdegrade.network.nets import SIZE_MULTIPLE, DomainShiftNet, LocalAffineNet, ShiftNetwork, check_batch
from camdegrade.synthetic import dead_leaves_images

__all__ = [
    "PRECISIONS",
    "SPARSE_MAX_LIVE",
    "SPARSE_MIN_PIXELS",
    "CpuInference",
    "CpuPlan",
    "LocalAffineInference",
    "Precision",
    "cpu_inference",
    "native_bfloat16",
    "probe_channel_order",
    "resolve_precision",
    "run_network",
]

#: How the network runs at inference: ``"float32"`` is the reference; ``"bfloat16"`` runs the convolutions and
#: products in bfloat16; ``"auto"`` picks bfloat16 where the device computes it natively, else float32.
Precision = Literal["auto", "float32", "bfloat16"]
PRECISIONS: tuple[str, ...] = ("auto", "float32", "bfloat16")
_DTYPES = {"float32": torch.float32, "bfloat16": torch.bfloat16}


def native_bfloat16(device: torch.device) -> bool:
    """Whether ``device`` computes bfloat16 convolutions natively (CUDA with bf16, or a CPU with AVX-512 BF16/AMX)."""
    if device.type == "cuda":  # emulated bfloat16 (before Ampere) is slower and less accurate than float32
        return torch.cuda.is_bf16_supported(including_emulation=False)
    if device.type == "cpu":
        return cpu_native_bfloat16()
    return False


def resolve_precision(precision: Precision, device: torch.device) -> str:
    """``"float32"`` or ``"bfloat16"``: the concrete precision for ``precision`` on ``device``."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {PRECISIONS}, got precision={precision!r}")
    if precision == "auto":
        return "bfloat16" if native_bfloat16(device) else "float32"
    return precision


def run_network(network: ShiftNetwork, image: Tensor, precision: Precision = "float32") -> Tensor:
    """The network's float32 output for ``image`` (float in [0, 1], or uint8 read as ``value / 255``), computed at
    ``precision`` (see :data:`Precision`).

    bfloat16 keeps 8-bit outputs within 1 level of float32 on ≥ 99.9 % of pixels of natural images (tested).
    On the CPU without autograd, both precisions run a plan (bfloat16 only where the CPU has it natively):
    :class:`CpuInference` for the paper's network, :class:`LocalAffineInference` for the local-affine one; elsewhere
    the module runs, under autocast for bfloat16.
    """
    concrete = resolve_precision(precision, image.device)
    if _plan_applies(network, image, concrete):
        return cpu_inference(network, _DTYPES[concrete]).run(image)
    if image.dtype == torch.uint8:
        image = bytes_to_unit(image)
    if concrete == "float32":
        if type(network) is DomainShiftNet:
            return network(image)
        # oneDNN's convolutions run fastest on channels-last input (the fit trains on it too)
        return network(image.contiguous(memory_format=torch.channels_last)).contiguous()
    with torch.autocast(image.device.type, dtype=torch.bfloat16):
        output = network(image.contiguous(memory_format=torch.channels_last))
    return output.float().contiguous()


def _plan_applies(network: ShiftNetwork, image: Tensor, concrete: str) -> bool:
    """Whether a CPU plan can stand in for the module: the paper's network (:class:`CpuInference` replaces its
    transposed convolutions) or the local-affine one (:class:`LocalAffineInference`), float32 weights and a uint8
    or float32 image on the CPU, bfloat16 only where the CPU computes it natively, and no graph to build."""
    if type(network) not in (DomainShiftNet, LocalAffineNet):
        return False
    if image.device.type != "cpu" or image.dtype not in (torch.uint8, torch.float32):
        return False
    if concrete == "bfloat16" and not native_bfloat16(image.device):
        return False
    tensors = list(module_tensors(network))
    if any(t.device.type != "cpu" or t.dtype != torch.float32 for t in tensors):
        return False
    if not torch.is_grad_enabled():
        return True
    return not (image.requires_grad or any(t.requires_grad for t in tensors))


_PLAN_CACHE: weakref.WeakKeyDictionary[ShiftNetwork, dict[Any, CpuPlan]] = weakref.WeakKeyDictionary()
_PLAN_LOCK = threading.Lock()


def cpu_inference(network: ShiftNetwork, dtype: torch.dtype) -> CpuPlan:
    """The cached plan of ``network`` in ``dtype``, rebuilt whenever one of its parameters (or the local-affine
    network's ``upsample``) changes."""
    fingerprint = tensors_fingerprint(module_tensors(network))
    key = (dtype, getattr(network, "upsample", None))
    with _PLAN_LOCK:
        plans = _PLAN_CACHE.setdefault(network, {})
        plan = plans.get(key)
        if plan is None or plan.fingerprint != fingerprint:
            plan = plans[key] = _new_plan(network, dtype, fingerprint)
        return plan


def _new_plan(network: ShiftNetwork, dtype: torch.dtype, fingerprint: tuple[int, ...]) -> CpuPlan:
    if isinstance(network, LocalAffineNet):
        return LocalAffineInference(network, dtype, fingerprint)
    if isinstance(network, DomainShiftNet):
        return CpuInference(network, dtype, fingerprint)
    raise TypeError(f"network must be a DomainShiftNet or a LocalAffineNet, got {type(network).__name__}")


class CpuInference:
    """``DomainShiftNet`` for CPU inference in float32 or bfloat16: the module's arithmetic up to rounding.

    - The encoder runs as channels-last convolutions (with the ReLU fused in, oneDNN's kernel, for native bfloat16).
    - Each 2×2/stride-2 transposed convolution maps every input pixel to its own 2×2 output block, so both decoders
      together are matrix products per encoder pixel: ``128 → (2·2·64)`` with ReLU, then block-
      diagonally, ``(2·2·64) → (3·4·4)``. The columns are ordered so that one strided copy lays the blocks out as
      an image; this replaces the transposed convolutions, the slowest part of the module on a CPU.
    - ReLU leaves many encoder channels at zero over a whole image (about half of them for the built-in profiles
      on natural photos). In float32, from :data:`SPARSE_MIN_PIXELS` encoder pixels up, the first decoder product
      leaves those out; they contribute exact zeros, so only the rounding order changes. In native bfloat16, where
      gathering the live columns costs more than the half product it saves (docs/performance.md, *The CPU plans'
      choices*), the channels are ordered once by a probe
      (:func:`probe_channel_order`) and the product runs over the prefix that ends at the last live one.
    - The pointwise curves (``curves=True``) run in float32; a byte image's input curve is a table lookup
      (:func:`byte_curve`, the same values).
    - Images are computed one at a time, so each gets the same bytes alone as in any batch or chunk.

    Args:
        network: the module; its weights are converted once (the plan does not follow later edits: see
            :func:`cpu_inference`, which rebuilds it when they change).
        dtype: ``torch.float32`` or ``torch.bfloat16``.
        fingerprint: the cache key of ``network``'s tensors the plan was built from.
    """

    def __init__(
        self, network: DomainShiftNet, dtype: torch.dtype = torch.float32, fingerprint: tuple[int, ...] = ()
    ) -> None:
        if dtype not in (torch.float32, torch.bfloat16):
            raise ValueError(f"dtype must be torch.float32 or torch.bfloat16, got dtype={dtype}")
        self.dtype = dtype
        self.fingerprint = fingerprint
        self._fused = use_fused_kernels(dtype)
        channels_last = torch.channels_last
        with torch.no_grad():
            # Native bfloat16 orders the encoder's output channels so that those a photograph leaves at zero come
            # last (a permutation of the hidden channels: the same function), and the first decoder product can
            # then skip them as a prefix instead of gathering columns (see _decode1).
            order = probe_channel_order(network) if self._fused else torch.arange(network.encode2.out_channels)
            layers = [
                (network.encode1.weight, network.encode1.bias),
                (network.encode2.weight[order], network.encode2.bias[order]),
            ]
            self.encode = [
                (weight.to(dtype).contiguous(memory_format=channels_last), bias.to(dtype)) for weight, bias in layers
            ]
            # bfloat16 holds 0…255 exactly, so uint8 images enter as their byte values and the first layer divides
            # by 255. float32 divides the image instead, so that uint8 and the same image in floats agree exactly.
            bytes_weight = network.encode1.weight / 255.0
            self.encode1_bytes_weight = bytes_weight.to(dtype).contiguous(memory_format=channels_last)
            first, second = network.decode1, network.decode2
            hidden, width = first.weight.shape[:2]
            # first.weight is (in, out, dy, dx); the product's outputs are ordered (dy, dx, c): a linear layer's
            # weight (out, in) = ((dy, dx, c), in).
            self.decode1_weight = (
                first.weight[order].permute(2, 3, 1, 0).reshape(4 * width, hidden).to(dtype).contiguous()
            )
            self.decode1_bias = first.bias.repeat(4).to(dtype)
            # Rows (dy, dx, c) as the first product's outputs; columns (k, dy, ey, dx, ex) = channel k, output row
            # 4i + 2dy + ey, column 4j + 2dx + ex, so that one permuted copy lays the 4×4 blocks out as an image.
            # Block-diagonal: each (dy, dx) block of the first product feeds only its own 2×2 outputs.
            blocks = torch.zeros(2, 2, width, 3, 2, 2, 2, 2)
            for dy in range(2):
                for dx in range(2):
                    blocks[dy, dx, :, :, dy, :, dx, :] = second.weight
            self.decode2_weight = blocks.reshape(4 * width, 48).to(dtype)
            self.decode2_bias = second.bias.repeat_interleave(16).to(dtype)

    def run(self, image: Tensor) -> Tensor:
        """``(N, 3, H, W)`` float in [0, 1] or uint8 → the network's float32 output, contiguous, same shape."""
        check_batch(image)
        n, _, height, width = image.shape
        pad_bottom, pad_right = -height % SIZE_MULTIPLE, -width % SIZE_MULTIPLE
        output = torch.empty(n, 3, height + pad_bottom, width + pad_right)
        with torch.no_grad():
            # One image at a time: which kernel a library picks can depend on the batch size, and with it the
            # rounding, so this is what keeps an image's bytes the same alone and in any batch.
            for index in range(n):
                hidden, first_weight = self._network_input(image[index : index + 1])
                if pad_bottom or pad_right:
                    hidden = F.pad(hidden, (0, pad_right, 0, pad_bottom), mode="replicate")
                self._run_aligned(hidden, first_weight, output[index])
            output.sigmoid_()
            if pad_bottom or pad_right:
                output = output[..., :height, :width].contiguous()
            return output

    def _network_input(self, image: Tensor) -> tuple[Tensor, Tensor]:
        """``image`` in ``dtype``, and the first layer's weight that reads it (plain NCHW: oneDNN's first convolution
        reads that faster than a channels-last copy can be made)."""
        if image.dtype == torch.uint8 and self.dtype == torch.bfloat16:
            return image.to(torch.bfloat16), self.encode1_bytes_weight
        unit = bytes_to_unit(image) if image.dtype == torch.uint8 else image.to(self.dtype)
        return unit, self.encode[0][0]

    def _run_aligned(self, image: Tensor, first_weight: Tensor, out: Tensor) -> None:
        """One ``(1, 3, H, W)`` network input with H and W multiples of 4 → its logits written into ``out``."""
        (_, first_bias), second = self.encode
        hidden = self._conv_relu(self._conv_relu(image, first_weight, first_bias), *second)
        rows, cols = hidden.shape[-2:]
        blocks = self._decode1(hidden.permute(0, 2, 3, 1).reshape(rows * cols, -1))
        # A permuted copy from float32 is several times faster than one that also converts from bfloat16.
        values = torch.addmm(self.decode2_bias, blocks, self.decode2_weight).float()
        out.view(3, rows, 4, cols, 4).copy_(values.view(rows, cols, 3, 4, 4).permute(2, 0, 3, 1, 4))

    def _decode1(self, pixels: Tensor) -> Tensor:
        """ReLU of the first decoder product for one image's encoder ``pixels`` ``(M, C)`` → ``(M, 4·width)``.

        Channels that are zero over the whole image contribute exact zeros, so they are left out: in float32 by
        gathering the live columns; in native bfloat16, where a gather costs more than it saves, as the channels
        after the last live one (a prefix, rounded up to 16; the plan ordered the channels for it)."""
        count, channels = pixels.shape
        if count < SPARSE_MIN_PIXELS:
            return self._linear_relu(pixels)
        live = pixels.amax(dim=0).nonzero().squeeze(1)  # ReLU outputs: a channel's maximum is 0 only if all are
        if self._fused:
            prefix = min(channels, -(-(int(live.max()) + 1 if live.numel() else 1) // 16) * 16)
            if prefix > SPARSE_MAX_LIVE * channels:
                return self._linear_relu(pixels)
            weight = self.decode1_weight[:, :prefix].contiguous()
            return FUSED_LINEAR(pixels[:, :prefix].contiguous(), weight, self.decode1_bias, "relu", [], "")
        return live_linear_relu(pixels, self.decode1_weight, self.decode1_bias, live)

    def _conv_relu(self, image: Tensor, weight: Tensor, bias: Tensor) -> Tensor:
        """ReLU(conv 3×3, stride 2, padding 1)."""
        return conv_relu(image, weight, bias, self._fused)

    def _linear_relu(self, rows: Tensor) -> Tensor:
        """ReLU(rows @ decode1_weightᵀ + decode1_bias)."""
        if self._fused:
            return FUSED_LINEAR(rows, self.decode1_weight, self.decode1_bias, "relu", [], "")
        return torch.addmm(self.decode1_bias, rows, self.decode1_weight.t()).relu_()


#: A CPU plan of a network: what :func:`cpu_inference` returns.
CpuPlan = CpuInference | LocalAffineInference


#: The probe that orders a network's hidden channels for the bfloat16 plan: a few generated dead-leaves images.
PROBE_IMAGES, PROBE_SIZE = 8, 96


def probe_channel_order(network: DomainShiftNet) -> Tensor:
    """The second encoder layer's output channels, most active first: sorted by their largest value before the
    ReLU over :data:`PROBE_IMAGES` dead-leaves images. Channels that photographs leave at zero (about half of
    them for the built-in profiles) come last: the live channels of photographs fill a prefix of 64 to 80 of 128.
    The order is fixed for a network (and a Pillow, which draws the probe): it sets only the summation order of the
    bfloat16 product, so an image's bytes still depend on nothing but the image. Draws nothing from torch's RNG."""
    images = bytes_to_unit(torch.stack(dead_leaves_images(PROBE_IMAGES, PROBE_SIZE, seed=0)))
    with torch.no_grad():
        first = network.encode1.weight.float(), network.encode1.bias.float()
        second = network.encode2.weight.float(), network.encode2.bias.float()
        hidden = F.conv2d(images, *first, stride=2, padding=1).relu_()
        highest = F.conv2d(hidden, *second, stride=2, padding=1).amax(dim=(0, 2, 3))
    return torch.argsort(highest, descending=True, stable=True)
