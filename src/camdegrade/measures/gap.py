"""The one scalar sim-to-real gap between two sets measured against the same clean images, and its spread.

Real and simulated sets share their clean images, so content cancels when the two are compared and a small
difference is significant. The gap is ``Σ_families RMS_k((value_k(real) − value_k(sim)) / tau_family)``: each
family contributes the root-mean-square of its components' differences in units of ``tau`` (on the family's
:meth:`~camdegrade.measures.base.PairedFamily.compare` scale), so one family off by one ``tau`` everywhere adds 1.
Components without enough data (an empty intensity bin) are left out.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from camdegrade.measures.base import FAMILIES
from camdegrade.measures.statistics import StatisticSet

__all__ = ["MAX_MISSING", "Scale", "bootstrap_indices", "family_gaps", "gap", "gap_spread", "measurement_scale"]

#: A component missing (too few pixels) from more than this share of the bootstrap resamples is left out.
MAX_MISSING = 0.1

Scale = dict[str, Tensor]


def family_gaps(
    real: StatisticSet, sim: StatisticSet, index: Tensor | None = None, scale: Scale | None = None
) -> dict[str, float]:
    """Per family, the RMS of ``(real − sim) / scale`` over the components both sets can measure; ``scale``
    defaults to ``tau`` (see :func:`measurement_scale`)."""
    real_values, sim_values = real.compared(index), sim.compared(index)
    out = {}
    for name, family in FAMILIES.items():
        unit = scale[name] if scale is not None else family.tau
        diff = (real_values[name] - sim_values[name]) / unit
        diff = diff[torch.isfinite(diff)]
        out[name] = float(diff.pow(2).mean().sqrt()) if diff.numel() else 0.0
    return out


def gap(real: StatisticSet, sim: StatisticSet, index: Tensor | None = None, scale: Scale | None = None) -> float:
    """The scalar sim-to-real gap: the sum of :func:`family_gaps`."""
    return sum(family_gaps(real, sim, index, scale).values())


def measurement_scale(real: StatisticSet, sim: StatisticSet, indices: Tensor) -> Scale:
    """Per component, ``sqrt(tau² + SE²)``: SE is the bootstrap standard error (over pairs) of the difference
    ``real − sim``. Statistics that the real data cannot pin down (a transfer ratio in a band where the content
    has little power, a noise bin with few pixels) then count for less. Computed once, against the profile as
    it is, and used as the fixed yardstick for every candidate and for the noise floor.

    A component that cannot be measured on more than :data:`MAX_MISSING` of the resamples rests on one or two
    pairs (an intensity bin only one image populates): its bootstrap spread is meaningless (near zero where it
    is measured) and it would enter and leave the gap from resample to resample. Its scale is NaN, which leaves
    it out of every gap."""
    rounds = []
    for index in indices:
        r, s = real.compared(index), sim.compared(index)
        rounds.append({name: r[name] - s[name] for name in FAMILIES})
    out = {}
    for name, family in FAMILIES.items():
        stacked = torch.stack([entry[name] for entry in rounds])
        finite = torch.isfinite(stacked)
        count = finite.sum(0).clamp_min(2)
        mean = torch.where(finite, stacked, 0).sum(0) / count
        variance = torch.where(finite, (stacked - mean) ** 2, 0).sum(0) / (count - 1)
        supported = finite.double().mean(0) >= 1.0 - MAX_MISSING
        out[name] = torch.where(supported, (family.tau**2 + variance).sqrt(), float("nan"))
    return out


def bootstrap_indices(count: int, rounds: int, seed: int) -> Tensor:
    """``(rounds, count)`` resamples of ``range(count)`` with replacement, from a seeded generator."""
    generator = torch.Generator().manual_seed(seed)
    return torch.randint(0, count, (rounds, count), generator=generator)


def gap_spread(real: StatisticSet, sims: Sequence[StatisticSet], indices: Tensor, scale: Scale | None = None) -> Tensor:
    """``(rounds, len(sims))`` gaps of each simulated set on every bootstrap resample of the pairs."""
    return torch.tensor([[gap(real, sim, index, scale) for sim in sims] for index in indices])
