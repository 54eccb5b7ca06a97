"""The edge spread of strong, isolated, near-axis step edges: how wide a camera makes a step, read from images alone.

Across each candidate step (a local maximum of the horizontal or vertical difference, the edge within about 11° of
the axis) the profile must run from one flat plateau to another of at least :data:`MIN_CONTRAST` levels; its width
is the distance from the 10 % to the 90 % crossing, interpolated. A set's statistic is the median over all such
steps of all its images. What texture puts in the top frequency bands (noise, aliasing, codec blocks) hardly moves
it: a step of 40 levels or more rises through 10–90 % in a few pixels whatever a few levels of noise do, and a
sharpened edge (overshoot) reads narrower, as it looks. On City100's 16 held-out iPhone X pairs the captures' median
is 3.10 px; the clean images blurred by a Gaussian of σ 1.25 px read 3.13 (the σ a paired least-squares fit gives:
1.27), and 6 levels of added noise move the captures' by 0.03 px (docs/results.md, *The unpaired fit's softness*).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor

from camdegrade.functional.analysis.images import luma

__all__ = ["MIN_CONTRAST", "median_step_width", "step_widths"]

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
    widths = [step_widths(image) for image in images]
    pooled = torch.cat(widths) if widths else torch.zeros(0, dtype=torch.float64)
    return (float(pooled.median()) if len(pooled) else float("nan")), len(pooled)
