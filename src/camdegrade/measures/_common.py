"""Small helpers the families share: sums to ratios, and the 4× low-pass that tone and colour are measured on."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

#: Fewest pixels behind a mean of a difference (an intensity bin).
MIN_COUNT = 64.0


def ratio(num: Tensor, den: Tensor) -> Tensor:
    """``num / den``, NaN where ``den`` is not positive."""
    return torch.where(den > 0, num / den.clamp_min(1e-12), torch.full_like(num, float("nan")))


def ratio_min_count(num: Tensor, den: Tensor) -> Tensor:
    """``num / den``, NaN where ``den`` (a count) is below :data:`MIN_COUNT`."""
    return torch.where(den >= MIN_COUNT, num / den.clamp_min(1e-12), torch.full_like(num, float("nan")))


def low(image: Tensor, factor: int = 4) -> Tensor:
    """``image`` averaged over ``factor``² blocks (as it is when smaller than ``4 * factor`` pixels)."""
    if min(image.shape[-2:]) < 4 * factor:
        return image
    return F.avg_pool2d(image[None], factor)[0]
