"""Colour kernels: the sRGB transfer function and colour matrices applied in linear light.

References:
    IEC 61966-2-1:1999, Multimedia systems and equipment — Colour measurement and management — Part 2-1: Colour
    management — Default RGB colour space — sRGB (the transfer function and its knees).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from camdegrade.functional._utils import ParamLike, apply_float, check_image, per_sample

__all__ = [
    "color_matrix_image",
    "linear_to_srgb",
    "linear_to_srgb_",
    "srgb_to_linear",
    "srgb_to_linear_",
    "white_balance_image",
]

_SRGB_KNEE = 0.04045
_LINEAR_KNEE = 0.0031308


def srgb_to_linear(image: Tensor) -> Tensor:
    """Decode sRGB-encoded floats to linear light (IEC 61966-2-1); differentiable, clamped to [0, 1]."""
    if not image.requires_grad:
        return srgb_to_linear_(image.clone())
    x = image.clamp(0.0, 1.0)
    curve = torch.exp2(torch.log2((x.clamp_min(_SRGB_KNEE) + 0.055) / 1.055) * 2.4)
    return curve + (x.clamp_max(_SRGB_KNEE) - _SRGB_KNEE) / 12.92


def linear_to_srgb(image: Tensor) -> Tensor:
    """Encode linear-light float values with the sRGB transfer function. Values are clamped to [0, 1]."""
    if not image.requires_grad:
        return linear_to_srgb_(image.clone())
    x = image.clamp(0.0, 1.0)
    curve = torch.exp2(torch.log2(x.clamp_min(_LINEAR_KNEE)) / 2.4) * 1.055 - 0.055
    return curve + (x.clamp_max(_LINEAR_KNEE) - _LINEAR_KNEE) * 12.92


# The in-place forms below compute the same curves with one temporary and as few passes as possible. Each curve is
# evaluated on values clamped to its knee, and the straight segment below the knee is added as (x − knee) · slope:
# torch.where and ``**`` are several times slower on the CPU, and fresh buffers cost more than the arithmetic.
# Constant factors are moved into the log domain or into the final add, where they cost no pass of their own.

_DECODE_LOG_OFFSET = -2.4 * math.log2(1.055)  # ((x + 0.055) / 1.055) ** 2.4 = exp2(2.4 · log2(x + 0.055) + this)


def srgb_to_linear_(image: Tensor) -> Tensor:
    """In-place :func:`srgb_to_linear` of a float tensor (no autograd); returns ``image``."""
    below = image.clamp(0.0, _SRGB_KNEE).sub_(_SRGB_KNEE)
    logs = image.clamp_(_SRGB_KNEE, 1.0).add_(0.055).log2_()
    torch.add(_scalar(_DECODE_LOG_OFFSET, image), logs, alpha=2.4, out=image).exp2_()
    return image.add_(below, alpha=1.0 / 12.92)


def linear_to_srgb_(image: Tensor) -> Tensor:
    """In-place :func:`linear_to_srgb` of a float tensor (no autograd); returns ``image``."""
    below = image.clamp(0.0, _LINEAR_KNEE).sub_(_LINEAR_KNEE)
    curve = image.clamp_(_LINEAR_KNEE, 1.0).log2_().div_(2.4).exp2_()
    torch.add(_scalar(-0.055, image), curve, alpha=1.055, out=image)
    return image.add_(below, alpha=12.92)


def _scalar(value: float, like: Tensor) -> Tensor:
    """``value`` as a 0-d tensor that broadcasts into one fused ``torch.add`` with ``like`` (a scalar ``alpha``
    scales only the second operand)."""
    return torch.tensor(value, dtype=like.dtype, device=like.device)


def color_matrix_image(image: Tensor, matrix: ParamLike, *, linear: bool = True) -> Tensor:
    """Mix the colour channels with a 3×3 matrix: ``out[c] = Σ_k matrix[c, k] · in[k]``.

    Args:
        image: ``[..., 3, H, W]`` uint8 or float in [0, 1] (sRGB-encoded).
        matrix: ``(3, 3)`` or per-sample ``(N, 3, 3)``; the identity is neutral.
        linear: apply the matrix in linear light (as a camera's colour-correction matrix does), then
            re-encode as sRGB.

    The result is clamped to [0, 1].
    """
    check_image(image)
    weights = per_sample(matrix, image, "matrix", (3, 3))

    def kernel(x: Tensor) -> Tensor:
        if linear:
            x = srgb_to_linear(x)
        mixed = torch.einsum("...ck,...khw->...chw", weights, x).clamp(0.0, 1.0)
        return linear_to_srgb(mixed) if linear else mixed

    return apply_float(image, kernel)


def white_balance_image(image: Tensor, gains: ParamLike, *, linear: bool = True) -> Tensor:
    """Scale each channel by a gain (``(3,)`` or per-sample ``(N, 3)``; ones are neutral) in linear light."""
    check_image(image)
    scale = per_sample(gains, image, "gains", (3,))[..., None, None]

    def kernel(x: Tensor) -> Tensor:
        if linear:
            return linear_to_srgb((srgb_to_linear(x) * scale).clamp(0.0, 1.0))
        return (x * scale).clamp(0.0, 1.0)

    return apply_float(image, kernel)
