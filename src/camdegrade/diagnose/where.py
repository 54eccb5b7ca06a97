"""Where the gap lies: one human-readable finding per statistic family, with its score and null band."""

from __future__ import annotations

from typing import Any

from camdegrade.measures import FAMILIES, StatisticSet


def suspects(axis: str) -> str:
    """The registered effects whose signature the family ``axis`` carries (a hint, the ranking decides), or
    ``"the network"`` when no effect explains it."""
    return ", ".join(FAMILIES[axis].suspects()) or "the network"


def findings(
    real: StatisticSet, sim: StatisticSet, scores: dict[str, float], nulls: dict[str, float]
) -> list[dict[str, Any]]:
    """One entry per family, largest score first: ``axis``, ``finding``, ``score``, ``null`` and ``significant``."""
    real_values, sim_values = real.values(), sim.values()
    out = []
    for name, family in FAMILIES.items():
        text = family.describe(real_values[name], sim_values[name], real)
        score = scores[name]
        null = nulls.get(name, 0.0)
        out.append(
            {
                "axis": name,
                "finding": f"{text} [suspects: {suspects(name)}]",
                "score": round(score, 4),
                "null": round(null, 4),
                "significant": score > max(3 * null, 1.0),
            }
        )
    return sorted(out, key=lambda entry: -entry["score"])
