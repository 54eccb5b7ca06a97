"""The strength of a fitted change, refined for its place in the chain (the fit itself sees the end of the chain,
where later stages, tone and codec, have transformed it)."""

from __future__ import annotations

import math
from collections.abc import Callable

import torch

from camdegrade.diagnose.heldout import MIN_REDUCTION
from camdegrade.effects import Effect

__all__ = ["STRENGTHS", "refine_strength"]

STRENGTHS = (0.6, 1.0, 1.6)


def refine_strength(
    effect: Effect, gap_of: Callable[[Effect], float], baseline: float | None, say: Callable[[str], None]
) -> tuple[Effect, float, float]:
    """Scale the fitted change so that the effect, at its place in the chain, best matches the calibration
    pairs. A candidate that does not lower the calibration gap (``baseline``) at all is left as fitted; with
    ``baseline`` None every strength is explored. Returns the effect, its strength and its calibration gap."""
    tried = {1.0: gap_of(effect)}
    if baseline is not None and tried[1.0] > baseline - MIN_REDUCTION:
        return effect, 1.0, tried[1.0]
    tried.update({strength: gap_of(effect.scaled(strength)) for strength in STRENGTHS if strength != 1.0})
    best = min(tried, key=tried.__getitem__)
    if best != 1.0:  # extend once past the edge of the bracket
        further = best * best
        tried[further] = gap_of(effect.scaled(further))
    vertex = _parabola_vertex(tried)
    if vertex is not None and all(abs(vertex - p) > 0.03 * p for p in tried):
        tried[vertex] = gap_of(effect.scaled(vertex))
    best = min(tried, key=tried.__getitem__)
    say(f"    {effect.name}: strength {best:.2f} (calibration gap {tried[best]:.2f}, at 1: {tried[1.0]:.2f})")
    return effect.scaled(best), best, tried[best]


def _parabola_vertex(tried: dict[float, float]) -> float | None:
    """The minimum, in log strength, of the parabola through the three best strengths tried (within 0.1–10)."""
    points = sorted(tried, key=tried.__getitem__)[:3]
    x = torch.tensor([math.log(p) for p in points], dtype=torch.float64)
    y = torch.tensor([tried[p] for p in points], dtype=torch.float64)
    try:
        a, b, _ = torch.linalg.solve(torch.stack([x * x, x, torch.ones_like(x)], 1), y).tolist()
    except RuntimeError:
        return None
    if a <= 0:
        return None
    return math.exp(min(max(-b / (2 * a), math.log(0.1)), math.log(10.0)))
