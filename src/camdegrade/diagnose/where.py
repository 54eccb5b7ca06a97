"""Where the gap lies: one human-readable finding per statistic family, with its score and null band, and what a
person sees beside them (the network's 4-pixel grid, texture too smooth or too sharp)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from torch import Tensor

from camdegrade.measures import FAMILIES, StatisticSet
from camdegrade.measures.families.blocks import Blocks, block_excess
from camdegrade.measures.visible import GridComparison, compare_grid, compare_texture

__all__ = ["GRID_SHARE", "findings", "suspects", "visible"]

#: The block-edge excess is the grid's when the middle of the blocks differs from it by at most this share of it.
GRID_SHARE = 0.5


def suspects(axis: str) -> str:
    """The registered effects whose signature the family ``axis`` carries (a hint, the ranking decides), or
    ``"the network"`` when no effect explains it."""
    return ", ".join(FAMILIES[axis].suspects()) or "the network"


def findings(
    real: StatisticSet,
    sim: StatisticSet,
    scores: dict[str, float],
    nulls: dict[str, float],
    grid: GridComparison | None = None,
) -> list[dict[str, Any]]:
    """One entry per family, largest score first: ``axis``, ``finding``, ``score``, ``null`` and ``significant``.
    With ``grid`` (the simulation's 4-pixel grid against the camera's), excess block-edge energy that the grid
    explains is laid at the network's door rather than the codec's."""
    real_values, sim_values = real.values(), sim.values()
    out = []
    for name, family in FAMILIES.items():
        text = family.describe(real_values[name], sim_values[name], real)
        blamed = suspects(name)
        if name == Blocks.name and _grid_explains_blocks(grid, real_values[name], sim_values[name]):
            blamed = f"the network's {grid.headline}, not a codec"  # type: ignore[union-attr]
        score = scores[name]
        null = nulls.get(name, 0.0)
        out.append(
            {
                "axis": name,
                "finding": f"{text} [suspects: {blamed}]",
                "score": round(score, 4),
                "null": round(null, 4),
                "significant": score > max(3 * null, 1.0),
            }
        )
    return sorted(out, key=lambda entry: -entry["score"])


def _grid_explains_blocks(grid: GridComparison | None, real: Tensor, sim: Tensor) -> bool:
    """Whether the block-edge energy the simulation has unlike the camera is its 4-pixel grid: the grid is seen, and
    the middle of the blocks differs from the camera's as their edges do (phases 3 and 7 are one phase of a 4-pixel
    period); a codec's blocking, in the simulation or in the camera, moves the edges alone."""
    if grid is None or not grid.significant:
        return False
    edge, mid = block_excess(real, sim)
    return math.isfinite(edge) and math.isfinite(mid) and abs(mid - edge) <= GRID_SHARE * abs(edge)


def visible(
    reals: Sequence[Tensor],
    before: Sequence[Tensor],
    after: Sequence[Tensor] | None = None,
    grid: GridComparison | None = None,
) -> list[dict[str, Any]]:
    """What a person sees, simulation (``before``: the profile as given) against capture: ``look`` (``grid``,
    ``texture``), ``finding`` (in words), ``significant``, the numbers ``before`` and, with ``after`` (the
    profile with the accepted changes), ``after`` and ``after_finding``. ``grid``: the grid of ``before``, when
    already compared."""
    out = []
    for look, compare in (("grid", compare_grid), ("texture", compare_texture)):
        measured = grid if look == "grid" and grid is not None else compare(before, reals)
        entry: dict[str, Any] = {"look": look, "finding": measured.describe(), "significant": measured.significant}
        entry["before"] = measured.to_dict()
        if after is not None:
            changed = measured if after is before else compare(after, reals)
            entry["after"] = changed.to_dict()
            entry["after_finding"] = changed.describe()
        out.append(entry)
    return out
