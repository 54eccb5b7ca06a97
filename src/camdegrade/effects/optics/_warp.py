"""Coarse-to-fine least-squares fitting of a parametric warp (distortion, chromatic aberration, shifts)."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch
from torch import Tensor

from camdegrade.effects._fitting import PairList, affine_residual, downscale, minimize

#: warp(image (1, 3, h, w), parameters, scale) → warped image; ``scale`` = this level's width / full width.
Warp = Callable[[Tensor, Tensor, float], Tensor]


def fit_warp(
    pairs: PairList,
    warp: Warp,
    initial: Sequence[float],
    unit: Sequence[float],
    *,
    max_side: int = 384,
    levels: Sequence[int] = (4, 2, 1),
    max_iter: int = 40,
    border: float = 0.05,
    align: bool = True,
) -> Tensor:
    """Parameters minimising ``Σ ||warp(source) − target||²`` over all pairs, coarse level first.

    Each level area-averages the images by a factor (a low-pass that widens the basin of convergence); the
    loss skips a ``border`` fraction of each side, where edge padding differs. Parameters are optimised in
    multiples of ``unit`` so that L-BFGS sees comparable scales. With ``align`` a per-pair, per-channel
    affine colour map is projected out of the loss, so small tone shifts of real pairs do not bias the
    geometry.
    """
    full_widths = [src.shape[-1] for src, _ in pairs]
    top = [(downscale(src, max_side), downscale(tgt, max_side)) for src, tgt in pairs]
    scale_unit = torch.tensor(unit, dtype=torch.float64)
    z = (torch.tensor(initial, dtype=torch.float64) / scale_unit).requires_grad_()
    for factor in levels:
        level = [
            (
                downscale(src, max(src.shape[-2:]) // factor)[None].double(),
                downscale(tgt, max(tgt.shape[-2:]) // factor)[None].double(),
            )
            for src, tgt in top
        ]

        def loss(level: list[tuple[Tensor, Tensor]] = level) -> Tensor:
            total = torch.zeros((), dtype=torch.float64)
            for (src, tgt), width in zip(level, full_widths, strict=True):
                warped = warp(src, z * scale_unit, src.shape[-1] / width)
                warped, tgt = _interior(warped, border), _interior(tgt, border)
                residual = affine_residual(warped, tgt) if align else warped - tgt
                total = total + residual.pow(2).mean()
            return total / len(level)

        minimize([z], loss, max_iter=max_iter)
    return (z * scale_unit).detach()


def _interior(image: Tensor, border: float) -> Tensor:
    height, width = image.shape[-2:]
    dy, dx = int(height * border), int(width * border)
    return image[..., dy : height - dy, dx : width - dx]
