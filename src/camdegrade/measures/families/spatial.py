"""The ``spatial`` family: where in the frame the image is brighter or darker than the clean one."""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
import torch.nn.functional as F
from torch import Tensor

from camdegrade.measures._common import ratio
from camdegrade.measures.base import MeasuredPair, PairedFamily, register_family

if TYPE_CHECKING:
    from camdegrade.measures.statistics import StatisticSet

__all__ = ["TILES", "Spatial", "tile_radius"]

TILES = 8
_CHANNELS = ("R", "G", "B")


def tile_radius(tiles: int) -> Tensor:
    """``(tiles, tiles)`` distance of each tile's centre from the frame centre, 1 at the corners."""
    centers = (torch.arange(tiles) + 0.5) / tiles - 0.5
    y, x = torch.meshgrid(centers, centers, indexing="ij")
    return torch.sqrt(x**2 + y**2) / (0.5 * 2**0.5)


@register_family
class Spatial(PairedFamily):
    """Mean of ``x − c`` on an 8×8 grid of tiles, per channel (vignetting, a tone or colour offset)."""

    name = "spatial"
    tau = 1.0
    unit = "8-bit levels"
    description = "mean of x − c on an 8×8 grid of tiles, per channel"

    def measure(self, pair: MeasuredPair) -> tuple[Tensor, Tensor]:
        x, c = pair.image, pair.clean
        tiles = min(TILES, *c.shape[-2:])
        num = F.adaptive_avg_pool2d((x - c)[None], tiles)[0]
        if tiles < TILES:
            num = F.interpolate(num[None], size=(TILES, TILES), mode="nearest")[0]
        return num.flatten(), torch.ones(num.numel())

    def reduce(self, num: Tensor, den: Tensor) -> Tensor:
        return ratio(num, den) * 255.0

    def describe(self, real: Tensor, sim: Tensor, real_set: StatisticSet) -> str:
        maps = (real - sim).reshape(3, TILES, TILES)
        luma = maps.mean(0)
        r2 = tile_radius(TILES).pow(2)
        design = torch.stack([torch.ones_like(r2), r2], -1).reshape(-1, 2)
        coef = torch.linalg.lstsq(design, luma.reshape(-1, 1)).solution[:, 0]
        mean = maps.mean((1, 2))
        return f"real − sim: {coef[1]:+.1f} levels from centre to corners (radial), mean offset " + ", ".join(
            f"{c} {m:+.1f}" for c, m in zip(_CHANNELS, mean.tolist(), strict=True)
        )
