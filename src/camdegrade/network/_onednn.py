"""oneDNN's fused CPU kernels and the products the networks' CPU plans share (leaf helper: torch only)."""

from __future__ import annotations

import functools
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor

__all__ = [
    "FUSED_CONV",
    "FUSED_LINEAR",
    "SPARSE_MAX_LIVE",
    "SPARSE_MIN_PIXELS",
    "conv_relu",
    "cpu_native_bfloat16",
    "live_linear_relu",
    "onednn_op",
    "use_fused_kernels",
]

#: Images with at least this many encoder pixels (a 128² image has 1024) have their first decoder product skip the
#: encoder channels that are zero over the whole image; below it, the product's fixed cost outweighs the saving.
SPARSE_MIN_PIXELS = 1024
#: Channels are skipped only when at most this share of them is non-zero: gathering the live ones costs a copy.
SPARSE_MAX_LIVE = 0.75


@functools.cache
def cpu_native_bfloat16() -> bool:
    """Whether this CPU computes bfloat16 convolutions natively (AVX-512 BF16 or AMX, as oneDNN reports it)."""
    return bool(torch.backends.mkldnn.is_available() and torch.ops.mkldnn._is_mkldnn_bf16_supported())


def conv_relu(image: Tensor, weight: Tensor, bias: Tensor, fused: bool) -> Tensor:
    """ReLU(conv 3×3, stride 2, padding 1); ``fused``: oneDNN's fused kernel (native bfloat16)."""
    if fused:
        return FUSED_CONV(image, weight, bias, [1, 1], [2, 2], [1, 1], 1, "relu", [], "")
    return F.conv2d(image, weight, bias, stride=2, padding=1).relu_()


def live_linear_relu(pixels: Tensor, weight: Tensor, bias: Tensor, live: Tensor | None = None) -> Tensor:
    """``ReLU(pixels @ weightᵀ + bias)`` (in their dtype) for ReLU outputs ``pixels`` ``(M, C)``.

    From :data:`SPARSE_MIN_PIXELS` rows up, the columns that are zero in every row (``live``: the others, found
    when not given) are left out where at most :data:`SPARSE_MAX_LIVE` of them are live: they add exact zeros, so
    only the rounding order changes."""
    count, channels = pixels.shape
    if count >= SPARSE_MIN_PIXELS:
        if live is None:
            live = pixels.amax(dim=0).nonzero().squeeze(1)  # a ReLU output's maximum is 0 only if all are
        if live.numel() <= SPARSE_MAX_LIVE * channels:
            return torch.addmm(bias, pixels.index_select(1, live), weight.index_select(1, live).t()).relu_()
    return torch.addmm(bias, pixels, weight.t()).relu_()


def use_fused_kernels(dtype: torch.dtype) -> bool:
    """Whether to call oneDNN's fused kernels (private torch ops that torch.compile uses): for native bfloat16 only.

    They raise for bfloat16 on CPUs without it, and in float32 they are no faster than the plain ops at 224² and
    cost more per call on small images (docs/performance.md, *The CPU plans' choices*)."""
    return dtype == torch.bfloat16 and FUSED_CONV is not None and FUSED_LINEAR is not None and cpu_native_bfloat16()


def onednn_op(name: str) -> Any:
    if not torch.backends.mkldnn.is_available():
        return None
    return getattr(torch.ops.mkldnn, name, None)


FUSED_CONV = onednn_op("_convolution_pointwise")
FUSED_LINEAR = onednn_op("_linear_pointwise")
