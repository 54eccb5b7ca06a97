"""Colour kernels: the sRGB transfer function and colour matrices applied in linear light."""

from __future__ import annotations

import torch
from torch import Tensor

from camdegrade.functional._utils import ParamLike, apply_float, check_image, per_sample

_SRGB_KNEE = 0.04045
_LINEAR_KNEE = 0.0031308


def srgb_to_linear(image: Tensor) -> Tensor:
    """Decode sRGB-encoded floats to linear light (IEC 61966-2-1); differentiable, clamped to [0, 1]."""
    x = image.clamp(0.0, 1.0)
    curve = ((x.clamp_min(_SRGB_KNEE) + 0.055) / 1.055) ** 2.4
    return torch.where(x <= _SRGB_KNEE, x / 12.92, curve)


def linear_to_srgb(image: Tensor) -> Tensor:
    """Encode linear-light float values with the sRGB transfer function. Values are clamped to [0, 1]."""
    x = image.clamp(0.0, 1.0)
    curve = 1.055 * x.clamp_min(_LINEAR_KNEE) ** (1.0 / 2.4) - 0.055
    return torch.where(x <= _LINEAR_KNEE, x * 12.92, curve)


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
