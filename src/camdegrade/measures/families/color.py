"""The ``color`` family: the linear-light 3×3 matrix from the clean image's colours to the image's."""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
from torch import Tensor

from camdegrade.functional import srgb_to_linear
from camdegrade.measures._common import low
from camdegrade.measures.base import MeasuredPair, PairedFamily, register_family

if TYPE_CHECKING:
    from camdegrade.measures.statistics import StatisticSet

__all__ = ["ColorMatrix"]

_CHANNELS = ("R", "G", "B")


@register_family
class ColorMatrix(PairedFamily):
    """3×3 linear-light least-squares matrix ``x ≈ M c`` on the low-passed images (well-exposed pixels only)."""

    name = "color"
    tau = 0.01
    unit = "matrix entry"
    description = "3×3 linear-light least-squares matrix x ≈ M c (low-passed)"

    def measure(self, pair: MeasuredPair) -> tuple[Tensor, Tensor]:
        low_x = srgb_to_linear(low(pair.image)).reshape(3, -1).double()
        low_c = srgb_to_linear(low(pair.clean)).reshape(3, -1).double()
        usable = ((low_c > 0.002) & (low_c < 0.9)).all(0) & ((low_x > 0.001) & (low_x < 0.95)).all(0)
        low_x, low_c = low_x[:, usable], low_c[:, usable]
        scale = float(max(1, low_c.shape[1]))
        return (low_x @ low_c.T / scale).flatten().float(), (low_c @ low_c.T / scale).flatten().float()

    def reduce(self, num: Tensor, den: Tensor) -> Tensor:
        xc = num.reshape(*num.shape[:-1], 3, 3).double()
        cc = den.reshape(*den.shape[:-1], 3, 3).double()
        ridge = 1e-9 * torch.eye(3, dtype=torch.float64)
        matrix = torch.linalg.solve(cc + ridge, xc.transpose(-1, -2)).transpose(-1, -2)
        return matrix.flatten(-2).float()

    def describe(self, real: Tensor, sim: Tensor, real_set: StatisticSet) -> str:
        matrix = (real - sim).reshape(3, 3)
        i, j = divmod(int(matrix.abs().argmax()), 3)
        gains = matrix.diagonal()
        return (
            f"real − sim colour matrix: largest {matrix[i, j]:+.3f} ({_CHANNELS[i]}←{_CHANNELS[j]}); diagonal "
            + ", ".join(f"{g:+.3f}" for g in gains.tolist())
        )
