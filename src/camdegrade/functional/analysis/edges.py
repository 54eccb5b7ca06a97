"""The edge spread of strong, isolated, near-axis step edges: how wide a camera makes a step, read from images alone.

Across each candidate step (a local maximum of the horizontal or vertical difference, the edge within about 11° of
the axis) the profile must run from one flat plateau to another of at least :data:`MIN_CONTRAST` levels; its width
is the distance from the 10 % to the 90 % crossing, interpolated. A set's statistic is the median over all such
steps of all its images. What texture puts in the top frequency bands (noise, aliasing, codec blocks) hardly moves
it: a step of 40 levels or more rises through 10–90 % in a few pixels whatever a few levels of noise do, and a
sharpened edge (overshoot) reads narrower, as it looks. On City100's 16 held-out iPhone X pairs the captures' median
is 3.10 px; the clean images blurred by a Gaussian of σ 1.25 px read 3.13 (the σ a paired least-squares fit gives:
1.27), and 6 levels of added noise move the captures' by 0.03 px (docs/results.md, *The unpaired fit's softness*).

And the half-maximum width of thin isolated near-axis lines (:func:`line_widths`): a ridge or a trough with flat,
level ground 4–7 px either side. A linear blur widens steps and lines alike; a camera that keeps steps crisp and
spreads thin strokes (a sensor of fewer pixels, upscaled and sharpened) does not: City100's iPhone X captures read
3.10 px for steps (like a Gaussian of σ 1.25) and 4.39 px for lines (like σ 1.75).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor

from camdegrade.functional.analysis.images import luma

__all__ = ["LINE_HEIGHT", "MIN_CONTRAST", "line_widths", "median_step_width", "pooled_median", "step_widths"]

#: The profile read across a step: ``HALF`` samples either side of it; the plateaus are ``PLATEAU`` samples from the
#: step (the pixels 4–7 from it), flat within :data:`PLATEAU_SPREAD` of the step's contrast, at least
#: :data:`MIN_CONTRAST` 8-bit levels apart.
HALF = 7
PLATEAU = (3, 6)
MIN_CONTRAST = 40.0
PLATEAU_SPREAD = 0.15
#: The edge's direction: the difference along the edge at most this share of the one across it (about 11°).
TILT = 0.2
LOW, HIGH = 0.1, 0.9


def _step_profiles(gray: Tensor) -> Tensor:
    """``(N, 2 * HALF)`` profiles across the near-vertical steps of ``gray`` (``(H, W)``, levels), each rising from
    0 (the left plateau's mean) to 1 (the right one's)."""
    across = gray[:, 1:] - gray[:, :-1]  # the step between x and x + 1
    along = torch.zeros_like(gray)
    along[1:-1] = (gray[2:] - gray[:-2]) / 2
    along = (along[:, 1:] + along[:, :-1]) / 2
    size = across.abs()
    peak = F.max_pool1d(size[:, None, :], 7, 1, 3)[:, 0, :]
    candidate = (size == peak) & (size > 0) & (along.abs() <= TILT * size)
    candidate[:2], candidate[-2:] = False, False
    candidate[:, :HALF], candidate[:, -HALF:] = False, False
    rows, cols = candidate.nonzero(as_tuple=True)
    offsets = torch.arange(-HALF + 1, HALF + 1)
    profile = gray[rows[:, None], cols[:, None] + offsets[None, :]]
    left = profile[:, HALF - 1 - PLATEAU[1] : HALF - PLATEAU[0]]
    right = profile[:, HALF + PLATEAU[0] : HALF + PLATEAU[1] + 1]
    low, contrast = left.mean(1), right.mean(1) - left.mean(1)
    spread = torch.maximum(left.amax(1) - left.amin(1), right.amax(1) - right.amin(1))
    kept = (contrast.abs() >= MIN_CONTRAST) & (spread <= PLATEAU_SPREAD * contrast.abs())
    return (profile[kept] - low[kept, None]) / contrast[kept, None]


def _crossing(profile: Tensor, level: float, before_centre: bool) -> tuple[Tensor, Tensor]:
    """Where each rising profile crosses ``level`` (interpolated sample position), the crossing nearest the step on
    its ``before_centre`` side; and which profiles have one."""
    index = torch.arange(profile.shape[1] - 1)
    crosses = (profile[:, :-1] < level) & (profile[:, 1:] >= level)
    centre = HALF - 1
    if before_centre:
        at = torch.where(crosses & (index <= centre), index, torch.full_like(index, -1)).amax(1)
    else:
        at = torch.where(crosses & (index >= centre), index, torch.full_like(index, profile.shape[1])).amin(1)
    found = (at >= 0) & (at < profile.shape[1] - 1)
    at = at.clamp(0, profile.shape[1] - 2)
    below, above = profile.gather(1, at[:, None])[:, 0], profile.gather(1, at[:, None] + 1)[:, 0]
    return at + (level - below) / (above - below).clamp_min(1e-9), found


def step_widths(image: Tensor) -> Tensor:
    """The 10–90 % rise (px) of every strong isolated near-axis step of ``image`` (``(3, H, W)``, float in [0, 1]
    or uint8), horizontal and vertical; empty where there is none.

    References:
        ISO 12233:2017, "Photography — Electronic still picture imaging — Resolution and spatial frequency
        responses" (the edge spread function and its 10–90 % rise distance).
    """
    if image.ndim != 3 or image.shape[0] != 3:
        raise ValueError(f"image must be a (3, H, W) RGB tensor, got shape {tuple(image.shape)}")
    unit = image.double() / 255.0 if image.dtype == torch.uint8 else image.double()
    gray = luma(unit) * 255.0
    widths = []
    for oriented in (gray, gray.T.contiguous()):
        if min(oriented.shape) <= 2 * HALF + 4:
            continue
        profiles = _step_profiles(oriented)
        start, has_start = _crossing(profiles, LOW, True)
        end, has_end = _crossing(profiles, HIGH, False)
        widths.append((end - start)[has_start & has_end])
    return torch.cat(widths) if widths else torch.zeros(0, dtype=torch.float64)


def median_step_width(images: Sequence[Tensor]) -> tuple[float, int]:
    """The median of :func:`step_widths` over all steps of ``images`` (NaN where none) and how many there are."""
    return pooled_median([step_widths(image) for image in images])


def pooled_median(widths: Sequence[Tensor]) -> tuple[float, int]:
    """The median of ``widths`` (one tensor per image) pooled, and how many there are; NaN where there are none."""
    pooled = torch.cat(list(widths)) if widths else torch.zeros(0, dtype=torch.float64)
    return (float(pooled.median()) if len(pooled) else float("nan")), len(pooled)


#: A thin line's profile: ``LINE_HALF`` samples either side of its peak; the ground is the samples
#: :data:`LINE_GROUND` from it, flat within :data:`LINE_SPREAD` of the line's height and level on both sides within as
#: much, the line at least :data:`LINE_HEIGHT` 8-bit levels above or below it.
LINE_HALF = 7
LINE_GROUND = (4, 7)
LINE_HEIGHT = 30.0
LINE_SPREAD = 0.2


def _line_profiles(gray: Tensor) -> Tensor:
    """``(N, 2 * LINE_HALF + 1)`` profiles across the near-vertical thin lines of ``gray`` (``(H, W)``, levels): a
    local extremum of the second difference along x with flat level ground either side; each 0 at the ground and 1
    at the peak."""
    second = torch.zeros_like(gray)
    second[:, 1:-1] = gray[:, 2:] + gray[:, :-2] - 2 * gray[:, 1:-1]
    size = second.abs()
    candidate = (size == F.max_pool1d(size[:, None, :], 5, 1, 2)[:, 0, :]) & (size > 0)
    along = torch.zeros_like(gray)
    along[1:-1] = (gray[2:] - gray[:-2]) / 2
    candidate[:2], candidate[-2:] = False, False
    candidate[:, :LINE_HALF], candidate[:, -LINE_HALF:] = False, False
    rows, cols = candidate.nonzero(as_tuple=True)
    profile = gray[rows[:, None], cols[:, None] + torch.arange(-LINE_HALF, LINE_HALF + 1)[None, :]]
    left = profile[:, LINE_HALF - LINE_GROUND[1] : LINE_HALF - LINE_GROUND[0] + 1]
    right = profile[:, LINE_HALF + LINE_GROUND[0] : LINE_HALF + LINE_GROUND[1] + 1]
    ground = (left.mean(1) + right.mean(1)) / 2
    height = (profile[:, LINE_HALF] - ground).abs()
    spread = torch.maximum(left.amax(1) - left.amin(1), right.amax(1) - right.amin(1))
    kept = (height >= LINE_HEIGHT) & ((left.mean(1) - right.mean(1)).abs() <= LINE_SPREAD * height)
    kept &= (spread <= LINE_SPREAD * height) & (along[rows, cols].abs() <= LINE_SPREAD * height)
    return (profile[kept] - ground[kept, None]) / (profile[kept, LINE_HALF] - ground[kept])[:, None]


def _half_widths(profile: Tensor) -> Tensor:
    """The distance between the 0.5 crossings either side of each profile's centre (interpolated), where both are
    inside the profile."""
    index = torch.arange(profile.shape[1] - 1)
    rises = (profile[:, :-1] < 0.5) & (profile[:, 1:] >= 0.5) & (index < LINE_HALF)
    falls = (profile[:, :-1] >= 0.5) & (profile[:, 1:] < 0.5) & (index >= LINE_HALF)
    start = torch.where(rises, index, torch.full_like(index, -1)).amax(1)
    end = torch.where(falls, index, torch.full_like(index, 10**6)).amin(1)
    found = (start >= 0) & (end < profile.shape[1] - 1)
    start, end, profile = start[found], end[found], profile[found]
    a0, a1 = profile.gather(1, start[:, None])[:, 0], profile.gather(1, start[:, None] + 1)[:, 0]
    b0, b1 = profile.gather(1, end[:, None])[:, 0], profile.gather(1, end[:, None] + 1)[:, 0]
    return (end + (b0 - 0.5) / (b0 - b1).clamp_min(1e-9)) - (start + (0.5 - a0) / (a1 - a0).clamp_min(1e-9))


def line_widths(image: Tensor) -> Tensor:
    """The half-maximum width (px) of every thin isolated near-axis line of ``image`` (``(3, H, W)``, float in
    [0, 1] or uint8), bright or dark, vertical and horizontal; empty where there is none.

    References:
        ISO 12233:2017 (the line spread function; here read from the scene's own thin lines, not a chart's).
    """
    if image.ndim != 3 or image.shape[0] != 3:
        raise ValueError(f"image must be a (3, H, W) RGB tensor, got shape {tuple(image.shape)}")
    unit = image.double() / 255.0 if image.dtype == torch.uint8 else image.double()
    gray = luma(unit) * 255.0
    widths = [
        _half_widths(_line_profiles(oriented))
        for oriented in (gray, gray.T.contiguous())
        if min(oriented.shape) > 2 * LINE_HALF + 4
    ]
    return torch.cat(widths) if widths else torch.zeros(0, dtype=torch.float64)
