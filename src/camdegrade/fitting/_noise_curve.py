"""A noise level table made smooth in the signal level, as a sensor's noise is, where the captures' own flat pixels
read it bin by bin.

A sensor's noise is Poisson–Gaussian in the raw signal (its variance affine in the signal), and a camera's tone
curve, demosaicking and denoising bend that smoothly: the std of a processed image's noise changes gradually from
one intensity to the next. The unpaired fit reads it per channel and intensity bin from each capture's own flat
pixels, and a bin often rests on one or two captures: where their "flat" pixels hold texture, that bin reads
several times the noise (10 PolyU crops of 128²: red bin 1 at 6.4 levels where each capture against its own mean
frame shows 2.8), and the calibration then raised it further (a table entry of 19.2 levels beside 0.3 and 0.7; flat
greys painted with 16–20 levels of green and magenta speckle; docs/results.md, "Unpaired fit on real PolyU
captures").

The table is therefore replaced by a smooth curve through it (:func:`smooth_levels`): per channel, the log std
that stays close to each bin's value, weighted by the bin's support (its flat pixels, :data:`HALF_SUPPORT`), and
whose second differences are small (:data:`CURVATURE`; an affine variance has almost none in the log std over
the middle of the range). Texture only adds to a bin's variance, so a bin far *above* the curve is down-weighted
(:data:`TEXTURE_LOG2`, iterated), one below it is not.

References:
    E. T. Whittaker, "On a new method of graduation", Proceedings of the Edinburgh Mathematical Society 41, 1923
    (the penalised smoother); P. H. C. Eilers, "A perfect smoother", Analytical Chemistry 75(14), 2003;
    A. Foi, M. Trimeche, V. Katkovnik, K. Egiazarian, "Practical Poissonian-Gaussian noise modeling and fitting for
    single-image raw-data", IEEE TIP 17(10), 2008 (noise levels per intensity from smooth regions, and the clipped
    Poisson–Gaussian curve they follow).
"""

from __future__ import annotations

import torch
from torch import Tensor

#: A bin with this many flat pixels counts half as much as one with very many (weight ``n / (n + HALF_SUPPORT)``).
HALF_SUPPORT = 2000.0
#: Weight of the squared second differences of the log2 std, and of the first differences (which keep the curve
#: flat, not extrapolated, beyond the bins that were measured).
CURVATURE = 1.0
SLOPE = 0.1
#: A bin this far above the curve (log2 std) keeps half its weight, twice as far a fifth: texture read as noise.
TEXTURE_LOG2 = 0.5
ROUNDS = 4
#: Levels below this (8-bit) are read as this in the log: a table entry at zero (the captures showing no more than
#: the clean set there) pulls the curve down, not to minus infinity.
FLOOR_LEVELS = 0.5


def smooth_levels(levels: Tensor, support: Tensor) -> Tensor:
    """``(3, K)`` std per channel and knot (units of [0, 1]; NaN: not measured) as the smooth curve through them
    (see the module), ``support`` ``(3, K)`` the flat pixels behind each knot. Channels with no measured knot stay
    as they were."""
    knots = levels.shape[-1]
    if knots < 3:
        return levels.clone()
    values = levels.double() * 255.0
    measured = torch.isfinite(values) & (support > 0)
    logs = torch.where(measured, values.clamp_min(FLOOR_LEVELS).log2(), torch.zeros_like(values))
    base_weight = torch.where(measured, support.double() / (support.double() + HALF_SUPPORT), torch.zeros_like(values))
    penalty = _penalty(knots)
    out = values.clone()
    for channel in range(values.shape[0]):
        if not bool(measured[channel].any()):
            continue
        weight = base_weight[channel]
        for _ in range(ROUNDS + 1):
            curve = torch.linalg.solve(torch.diag(weight) + penalty, weight * logs[channel])
            above = (logs[channel] - curve).clamp_min(0.0)
            weight = base_weight[channel] / (1.0 + (above / TEXTURE_LOG2) ** 2)
        out[channel] = curve.exp2()
    return (out / 255.0).to(levels.dtype)


def _penalty(knots: int) -> Tensor:
    second = torch.zeros(knots - 2, knots, dtype=torch.float64)
    first = torch.zeros(knots - 1, knots, dtype=torch.float64)
    for row in range(knots - 2):
        second[row, row : row + 3] = torch.tensor([1.0, -2.0, 1.0], dtype=torch.float64)
    for row in range(knots - 1):
        first[row, row : row + 2] = torch.tensor([-1.0, 1.0], dtype=torch.float64)
    ridge = 1e-6 * torch.eye(knots, dtype=torch.float64)  # a channel measured at one knot only: flat through it
    return CURVATURE * second.T @ second + SLOPE * first.T @ first + ridge
