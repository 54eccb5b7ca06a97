"""The unpaired fit's judges. The captures and the clean set show *different* scenes, so their set statistics differ
by content too: a stage is kept only where the change it makes exceeds both a floor and what the content alone moves
it by, the standard error from random half-splits of both sets (:func:`split_half_error`)."""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor

from camdegrade._seeds import derived_generator

__all__ = ["SIGNIFICANCE", "SPLITS", "significant", "split_half_error"]

#: Random half-splits behind a standard error, and how many of them a kept change must exceed.
SPLITS = 8
SIGNIFICANCE = 3.0


def split_half_error(
    estimate: Callable[[list[int], list[int]], Tensor], captures: int, cleans: int, seed: int
) -> Tensor:
    """The standard error of ``estimate(capture indices, clean indices)`` over the whole sets, from
    :data:`SPLITS` random half-splits of both: RMS of half the difference of the two halves' estimates (each half
    has twice the full set's variance). What the content of the images alone moves the estimate by."""
    generator = derived_generator(seed, "unpaired-split")
    halves = []
    for _ in range(SPLITS):
        a, b = (
            torch.randperm(captures, generator=generator).tolist(),
            torch.randperm(cleans, generator=generator).tolist(),
        )
        first = estimate(a[: captures // 2], b[: cleans // 2])
        second = estimate(a[captures // 2 :], b[cleans // 2 :])
        halves.append((first - second) / 2)
    return torch.stack(halves).pow(2).mean(0).sqrt()


def significant(change: Tensor, error: Tensor, floor: float) -> bool:
    """Whether some component of ``change`` exceeds both ``floor`` and :data:`SIGNIFICANCE` standard errors."""
    return bool((change.abs() > torch.clamp(SIGNIFICANCE * error, min=floor)).any())
