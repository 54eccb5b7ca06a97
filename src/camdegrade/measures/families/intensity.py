"""The ``intensity`` family: the tone residual as a function of the clean value."""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
from torch import Tensor

from camdegrade.measures._common import low, ratio_min_count
from camdegrade.measures.base import MeasuredPair, PairedFamily, register_family

if TYPE_CHECKING:
    from camdegrade.measures.statistics import StatisticSet

__all__ = ["INTENSITY_BINS", "Intensity"]

INTENSITY_BINS = 16


@register_family
class Intensity(PairedFamily):
    """Mean of the low-passed ``x − c`` in 16 bins of clean value, per channel (a tone curve, a colour offset)."""

    name = "intensity"
    tau = 1.0
    unit = "8-bit levels"
    description = "mean of low-passed x − c in 16 bins of clean value, per channel"

    def measure(self, pair: MeasuredPair) -> tuple[Tensor, Tensor]:
        low_x, low_c = low(pair.image), low(pair.clean)
        key = (low_c * INTENSITY_BINS).long().clamp(0, INTENSITY_BINS - 1) + torch.arange(3)[:, None, None] * (
            INTENSITY_BINS
        )
        size = 3 * INTENSITY_BINS
        num = torch.bincount(key.flatten(), weights=(low_x - low_c).flatten().double(), minlength=size)
        den = torch.bincount(key.flatten(), minlength=size).double()
        return num.float(), den.float()

    def reduce(self, num: Tensor, den: Tensor) -> Tensor:
        """Mean of a difference in [0, 1] units → 8-bit levels."""
        return ratio_min_count(num, den) * 255.0

    def describe(self, real: Tensor, sim: Tensor, real_set: StatisticSet) -> str:
        table = (real - sim).reshape(3, INTENSITY_BINS)
        luma = torch.nanmean(table, 0)
        valid = torch.isfinite(luma)
        if not bool(valid.any()):
            return "no populated intensity bins"
        worst = int(torch.where(valid, luma.abs(), torch.tensor(-1.0)).argmax())
        centre = (worst + 0.5) / INTENSITY_BINS
        return f"real − sim tone residual up to {luma[worst]:+.1f} levels at clean value {centre:.2f}"
