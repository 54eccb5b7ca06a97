"""The blur by the captures' edge spread, and a guard on every stage that sharpens (issue 43).

A set-level spectrum can be matched by edge sharpening where a camera's top band is aliasing, noise and codec
texture: power of the right amount in the wrong form. The width of strong isolated step edges
(:func:`~camdegrade.functional.analysis.edges.step_widths`) is a statistic such texture hardly moves. So the blur is
chosen among those whose simulation of the clean set has the captures' median step width (within
:data:`EDGE_TOLERANCE`), and a sharpening amount or a
detail response is kept only where it does not take the simulation's median step width farther from the captures'
than it was without it (:data:`EDGE_SLACK`, or the captures' own split-half spread)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from itertools import pairwise

import torch
from torch import Tensor

from camdegrade._support.seeds import derived_generator
from camdegrade.fitting.unpaired.bench import UnpairedFit
from camdegrade.fitting.unpaired.judges import SIGNIFICANCE, SPLITS
from camdegrade.functional.analysis.edges import step_widths

__all__ = [
    "EDGE_SLACK",
    "EDGE_TOLERANCE",
    "EdgeSpread",
    "blur_by_edges",
    "captures_edge_spread",
    "farther",
    "rounded",
    "sharpens_away",
    "simulated_width",
]

#: How far (px) from the captures' median step width a blur may leave the simulation's where that brings the
#: spectrum closer: a tone curve fitted between different scenes changes an edge's shape (the test suite's combined
#: camera: its true blur reads 0.12 px wider through the fitted chain than through its own).
EDGE_TOLERANCE = 0.25
#: How much farther (px) a sharpening stage may take the simulation's median step width from the captures' than its
#: blur alone left it, at least: random halves of City100's 20 captures differ by 0.04 px.
EDGE_SLACK = 0.05
#: Fewer steps than this on a side: the width is not measured and the spectrum alone decides.
MIN_STEPS = 50


class EdgeSpread:
    """The captures' median step width (px), how many steps it rests on, and the tolerance a sharpening stage
    and a sharpening stage are held to (:data:`EDGE_TOLERANCE`, :data:`EDGE_SLACK`), each at least
    :data:`~camdegrade.fitting.unpaired.judges.SIGNIFICANCE` standard errors of the median over random half-splits
    of the captures (``error``)."""

    def __init__(self, width: float, steps: int, error: float) -> None:
        self.width, self.steps = width, steps
        spread = SIGNIFICANCE * error if math.isfinite(error) else 0.0
        self.tolerance, self.slack = max(EDGE_TOLERANCE, spread), max(EDGE_SLACK, spread)

    @property
    def measured(self) -> bool:
        return self.steps >= MIN_STEPS and math.isfinite(self.width)

    def record(self) -> dict:
        return {
            "captures": rounded(self.width),
            "steps": self.steps,
            "tolerance": round(self.tolerance, 3),
            "slack": round(self.slack, 3),
        }


def _median(per_image: Sequence[Tensor]) -> tuple[float, int]:
    pooled = torch.cat(list(per_image)) if per_image else torch.zeros(0, dtype=torch.float64)
    return (float(pooled.median()) if len(pooled) else math.nan), len(pooled)


def captures_edge_spread(fit: UnpairedFit) -> EdgeSpread:
    """The captures' :class:`EdgeSpread`, measured once per fit (kept in ``fit.sets``)."""
    if fit.sets.edge_spread is None:
        per_image = [step_widths(image) for image in fit.captures.images]
        width, steps = _median(per_image)
        generator = derived_generator(fit.seed, "unpaired-edges")
        halves = []
        for _ in range(SPLITS):
            order = torch.randperm(len(per_image), generator=generator).tolist()
            half = len(order) // 2
            first, second = _median([per_image[i] for i in order[:half]]), _median([per_image[i] for i in order[half:]])
            halves.append((first[0] - second[0]) / 2)
        error = math.sqrt(sum(value * value for value in halves) / len(halves)) if halves else math.nan
        fit.sets.edge_spread = EdgeSpread(width, steps, error)
    return fit.sets.edge_spread


def simulated_width(images: Sequence[Tensor]) -> float:
    """The median step width of simulated images (NaN with fewer than :data:`MIN_STEPS` steps)."""
    width, steps = _median([step_widths(image) for image in images])
    return width if steps >= MIN_STEPS else math.nan


def blur_by_edges(widths: dict[float, float], target: float) -> float | None:
    """The blur sigma whose simulation has the median step width ``target``: ``widths`` (sigma → width, without
    sharpening) interpolated linearly between the two sigmas that bracket it, to 0.05 px; the nearest end where
    none does; ``None`` where no width was measured."""
    known = sorted((sigma, width) for sigma, width in widths.items() if math.isfinite(width))
    if not known:
        return None
    for (s0, w0), (s1, w1) in pairwise(known):
        if min(w0, w1) <= target <= max(w0, w1) and w0 != w1:
            return round((s0 + (target - w0) / (w1 - w0) * (s1 - s0)) * 20) / 20
    return min(known, key=lambda item: abs(item[1] - target))[0]


def farther(spread: EdgeSpread, without: float, with_stage: float) -> bool:
    """Whether a stage takes the simulation's median step width farther from the captures' than it was
    ``without`` it, and beyond the tolerance (never where a width is not measured)."""
    if not (spread.measured and math.isfinite(without) and math.isfinite(with_stage)):
        return False
    allowed = max(abs(without - spread.width), spread.tolerance)
    return abs(with_stage - spread.width) > allowed


def sharpens_away(spread: EdgeSpread, unsharpened: float, sharpened: float) -> bool:
    """Whether a sharpening stage takes the simulation's median step width farther from the captures' than
    ``unsharpened`` (without it) by more than the slack; also where a width is not measured but the captures' is
    (a stage the statistic cannot vouch for is refused)."""
    if not spread.measured:
        return False
    if not (math.isfinite(unsharpened) and math.isfinite(sharpened)):
        return True
    return abs(sharpened - spread.width) > abs(unsharpened - spread.width) + spread.slack


def rounded(width: float) -> float | None:
    """``width`` to 0.001 px for a record, ``None`` where it is not measured (NaN has no JSON)."""
    return round(width, 3) if math.isfinite(width) else None
