"""The ``blocks`` family: gradient energy at each phase of the 8×8 grid (JPEG blocking, the network's grid)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
from torch import Tensor

from camdegrade.functional.analysis.images import luma
from camdegrade.measures._common import ratio
from camdegrade.measures.base import MeasuredPair, PairedFamily, register_family

if TYPE_CHECKING:
    from camdegrade.measures.statistics import StatisticSet

__all__ = ["Blocks", "block_excess", "block_phase_energy"]


def block_phase_energy(image: Tensor) -> tuple[Tensor, Tensor]:
    """``(16,)`` mean luma gradient at each of the 8 column, then 8 row phases of the 8×8 grid, and ``(16,)`` the
    mean over the phases of each direction (zeros where the image is narrower than 8 pixels)."""
    gray = luma(image)
    gx = (gray[:, 1:] - gray[:, :-1]).abs()
    gy = (gray[1:, :] - gray[:-1, :]).abs()
    out = []
    for grad, axis in ((gx, 1), (gy, 0)):
        length = grad.shape[axis] // 8 * 8
        if length < 8:
            out.append(torch.zeros(8))
            continue
        trimmed = grad[:, :length] if axis == 1 else grad[:length, :]
        profile = trimmed.mean(1 - axis).reshape(-1, 8).mean(0)
        out.append(profile)
    num = torch.cat(out)
    den = torch.cat([o.mean().expand(8) for o in out])
    return num, den


@register_family
class Blocks(PairedFamily):
    """Luma gradient energy at each of the 8 column/row phases of the 8×8 grid, relative to the mean."""

    name = "blocks"
    tau = 0.01
    unit = "relative gradient energy"
    description = "luma gradient energy at each of the 8 column/row phases of the 8×8 grid, relative to the mean"
    network_fault = "the stride-2 transposed convolutions' 4-pixel pattern"
    pixel_pattern = True

    def measure(self, pair: MeasuredPair) -> tuple[Tensor, Tensor]:
        return block_phase_energy(pair.image)

    def reduce(self, num: Tensor, den: Tensor) -> Tensor:
        return ratio(num, den)

    def describe(self, real: Tensor, sim: Tensor, real_set: StatisticSet) -> str:
        edge = (real[7] + real[15]) / 2
        simulated = (sim[7] + sim[15]) / 2
        if not bool(torch.isfinite(edge)):
            return "block-edge energy not measurable: the captures have no gradients (too little texture)"
        return f"gradient energy on 8×8 block edges: real {edge:.2f}× the mean vs sim {simulated:.2f}×"


def block_excess(real: Tensor, sim: Tensor) -> tuple[float, float]:
    """``(edge, mid)``: how much more relative gradient energy the simulation has than the camera on the 8×8 block
    edges (phase 7) and in the middle of the blocks (phase 3), mean of columns and rows, from the :class:`Blocks`
    values. A codec's blocking moves the edge alone; a 4-pixel grid moves both alike (its period divides 8)."""
    excess = sim - real
    return float((excess[7] + excess[15]) / 2), float((excess[3] + excess[11]) / 2)
