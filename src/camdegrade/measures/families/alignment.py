"""The ``alignment`` family: per-tile, per-channel displacement of the image against the clean one.

References:
    B. D. Lucas, T. Kanade, "An iterative image registration technique with an application to stereo vision",
    IJCAI 1981.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
import torch.nn.functional as F
from torch import Tensor

from camdegrade.functional.analysis.images import box_mean
from camdegrade.measures.base import MeasuredPair, PairedFamily, register_family

if TYPE_CHECKING:
    from camdegrade.measures.statistics import StatisticSet

__all__ = ["SHIFT_TILES", "Alignment"]

SHIFT_TILES = 4


@register_family
class Alignment(PairedFamily):
    """Per-tile (4×4), per-channel displacement of ``x`` against ``c`` (Lucas–Kanade with a per-tile affine
    intensity map projected out): misalignment, distortion, chromatic aberration. A cross-statistic with the clean
    image, so independent noise averages out of it."""

    name = "alignment"
    geometric = True
    tau = 0.05
    unit = "pixels"
    description = "per-tile (4×4), per-channel displacement of x against c (Lucas–Kanade, affine intensity out)"

    def measure(self, pair: MeasuredPair) -> tuple[Tensor, Tensor]:
        x, c = pair.image, pair.clean
        factor = 2 if min(c.shape[-2:]) >= 192 else 1  # large images: half resolution, gradients per full pixel
        if factor > 1:
            smooth_x, smooth_c = F.avg_pool2d(x[None], factor)[0], F.avg_pool2d(c[None], factor)[0]
        else:
            smooth_x, smooth_c = box_mean(x, 3), box_mean(c, 3)
        gx = (F.pad(smooth_c[..., :, 2:] - smooth_c[..., :, :-2], (1, 1), mode="replicate")) / (2 * factor)
        gy = (F.pad(smooth_c[..., 2:, :] - smooth_c[..., :-2, :], (0, 0, 1, 1), mode="replicate")) / (2 * factor)
        error = smooth_x - smooth_c
        design = torch.stack([torch.ones_like(smooth_c), smooth_c, gx, gy], 1)  # (3, 4, H, W)
        height, width = smooth_c.shape[-2:]
        border = max(2, min(height, width) // 32)
        design = design[..., border : height - border, border : width - border]
        error = error[..., border : height - border, border : width - border]
        tiles = min(SHIFT_TILES, *design.shape[-2:])
        products = (design[:, :, None] * design[:, None, :]).reshape(3, 16, *design.shape[-2:])
        den = F.adaptive_avg_pool2d(products, tiles)  # (3, 16, T, T)
        num = F.adaptive_avg_pool2d(design * error[:, None], tiles)  # (3, 4, T, T)
        den = den.permute(2, 3, 0, 1).reshape(tiles * tiles, 3, 16)
        num = num.permute(2, 3, 0, 1).reshape(tiles * tiles, 3, 4)
        return num, den

    def reduce(self, num: Tensor, den: Tensor) -> Tensor:
        """Solve the summed per-tile normal equations of ``e ≈ α + β c − d·∇c`` and return ``d`` in pixels."""
        b = num.double()  # (..., T, 3, 4)
        a = den.double().reshape(*den.shape[:-1], 4, 4)
        scale = a.diagonal(dim1=-2, dim2=-1).mean(-1, keepdim=True)[..., None].clamp_min(1e-12)
        solution = torch.linalg.solve(a + 1e-6 * scale * torch.eye(4, dtype=torch.float64), b[..., None])[..., 0]
        texture = a[..., 2, 2] + a[..., 3, 3]
        shift = -solution[..., 2:]
        weak = texture < 1e-3 * texture.flatten().max().clamp_min(1e-12)
        shift = torch.where(weak[..., None], torch.full_like(shift, float("nan")), shift)
        return shift.flatten(-3).float()

    def describe(self, real: Tensor, sim: Tensor, real_set: StatisticSet) -> str:
        if not bool(torch.isfinite(real).any()):
            return "displacement not measurable: the clean images have too little texture in every tile"
        shifts = (real - sim).reshape(SHIFT_TILES * SHIFT_TILES, 3, 2)
        mean = torch.nanmean(shifts[:, 1], 0)
        centers = (torch.arange(SHIFT_TILES) + 0.5) / SHIFT_TILES - 0.5
        y, x = torch.meshgrid(centers, centers, indexing="ij")
        direction = torch.stack([x.flatten(), y.flatten()], -1)
        green = shifts[:, 1] - mean
        radial = torch.nanmean((green * direction).sum(-1) / direction.pow(2).sum(-1).clamp_min(1e-6))
        chroma = []
        for channel in (0, 2):
            relative = shifts[:, channel] - shifts[:, 1]
            chroma.append(float(torch.nanmean((relative * direction).sum(-1) / direction.pow(2).sum(-1))))
        return (
            f"real − sim shift (green) dx {mean[0]:+.2f}, dy {mean[1]:+.2f} px; radial scale {radial:+.2f} px per "
            f"half-width; red/blue vs green radial {chroma[0]:+.2f}/{chroma[1]:+.2f}"
        )
