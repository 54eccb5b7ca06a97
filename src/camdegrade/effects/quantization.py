"""ISP stage: an image buffer of few levels (an ADC, or a buffer of few bits before a tone table)."""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping
from typing import ClassVar

import torch
from torch import Tensor

from camdegrade.effects._fitting import as_pairs
from camdegrade.effects.base import Effect, Pairs, check_range, register_effect, shown
from camdegrade.functional.quantization import (
    code_histogram,
    histogram_comb,
    histogram_peaks,
    quantize_image,
    uniform_codebook,
)

__all__ = ["Quantization"]


@register_effect
class Quantization(Effect):
    """Every value snapped to the nearest of ``levels`` levels per channel (kernel
    :func:`~camdegrade.functional.quantization.quantize_image`).

    The levels are the ``codebook``: evenly spaced for an ADC or a buffer of ``log2(levels)`` bits at the output;
    for a buffer quantized *before* a tone curve, the curve's values at the evenly spaced levels (the tone applied to
    already-quantized values: the output holds only those values, and posterises gradients). It sits in the ISP
    before a ``resolution`` stage (:attr:`precedes`: the ISP's upscale interpolates the quantized buffer, as a
    camera's does).

    Args:
        levels: the number of levels per channel, from 2 to 256 (256, the default with an even codebook: none).
        codebook: ``(3, levels)`` values in [0, 1], non-decreasing along each row (default: evenly spaced).

    Valid values (:meth:`check_values`): ``levels`` from 2 to 256; ``codebook`` in [0, 1], non-decreasing rows.

    References:
        R. M. Gray, D. L. Neuhoff, "Quantization", IEEE Trans. Information Theory 44(6), 1998.
    """

    name = "quantization"
    stage = "isp"
    precedes = ("resolution",)
    explains = ("comb",)
    fit_budget = 32
    MAX_LEVELS: ClassVar[int] = 256
    #: The most levels a fit or a rescaling gives (7 bits): a buffer of 8 bits before a tone table skips single
    #: codes only, which the profile's network already places within a level.
    MAX_FITTED_LEVELS: ClassVar[int] = 128
    #: The targets' code histogram must be combed (:func:`~camdegrade.functional.quantization.histogram_comb`) by at
    #: least this much more than the sources' for a fit to find levels (half the ``comb`` family's tau; an 8-bit
    #: buffer through a contrast table combs by 0.15, a 5-bit buffer upscaled by 0.12, one not upscaled by 1.5).
    MIN_COMB: ClassVar[float] = 0.05
    codebook: Tensor

    def __init__(self, levels: int = 256, codebook: Tensor | None = None) -> None:
        super().__init__()
        if isinstance(levels, bool) or not isinstance(levels, int) or not 2 <= levels <= self.MAX_LEVELS:
            raise ValueError(f"levels must be an integer from 2 to {self.MAX_LEVELS}, got levels={levels!r}")
        values = uniform_codebook(levels) if codebook is None else torch.as_tensor(codebook, dtype=torch.float32)
        if tuple(values.shape) != (3, levels):
            raise ValueError(f"codebook must have shape (3, {levels}), got shape {tuple(values.shape)}")
        self.levels = levels
        self.register_buffer("codebook", values.detach().clone())
        self.check_values()

    def check_values(self) -> None:
        super().check_values()
        check_range("codebook", self.codebook, 0.0, 1.0)
        if bool((self.codebook[:, 1:] < self.codebook[:, :-1]).any()):
            raise ValueError(f"codebook must be non-decreasing along each row, got codebook={shown(self.codebook)}")

    @property
    def bits(self) -> float:
        """``log2(levels)``: the buffer's bit depth (5 for 32 levels)."""
        return math.log2(self.levels)

    def config(self) -> dict[str, int]:
        return {"levels": self.levels}

    def magnitude(self) -> float:
        """The mean spacing of the levels in 8-bit codes, as bits lost: ``log2(255 / (levels − 1))`` (0 at 256)."""
        return math.log2(255.0 / (self.levels - 1))

    def scaled(self, strength: float) -> Quantization:
        """A copy whose levels are ``strength`` times as far apart (the same curve through them), at most
        :attr:`MAX_FITTED_LEVELS` of them; strength 0 (or below) is the neutral stage."""
        if strength <= 0:
            return type(self).neutral()
        levels = min(max(round((self.levels - 1) / strength) + 1, 2), max(self.MAX_FITTED_LEVELS, self.levels))
        return type(self)(levels, resample_levels(self.codebook, levels))

    def forward(self, image: Tensor, params: Mapping[str, Tensor] | None = None) -> Tensor:
        return quantize_image(image, self.codebook)

    @classmethod
    def fit(cls, source: Pairs, target: Pairs) -> Quantization:
        """The levels the targets hold: per channel the peaks of the targets' 8-bit code histogram
        (:func:`~camdegrade.functional.quantization.histogram_peaks`), continued at their end spacings to 0 and 1
        and resampled to the median count of the channels (at most :attr:`MAX_FITTED_LEVELS`); the neutral stage
        unless the targets' histogram is combed :attr:`MIN_COMB` more than the sources'. The histogram cannot tell
        a coarse buffer smoothed by a later upscale from single codes skipped by a tone table (both comb it by
        0.12–0.2): where the stage sits in a chain, the chain's simulation decides (the diagnosis's gap). Recovers
        the 32 levels of a foreign camera's 5-bit buffer before its tone table exactly
        (``tests/test_quantization.py``)."""
        pairs = as_pairs(source, target)
        histograms = [sum(code_histogram(image) for image in images) for images in zip(*pairs, strict=True)]
        combs = [comb / mean.clamp_min(1e-12) for comb, mean in map(histogram_comb, histograms)]
        peaks = [histogram_peaks(row) for row in histograms[1]]
        if float((combs[1] - combs[0]).mean()) < cls.MIN_COMB or min(len(p) for p in peaks) < 2:
            return cls.neutral()
        levels = min(int(torch.tensor([len(p) for p in peaks]).median()), cls.MAX_FITTED_LEVELS)
        codebook = torch.stack([resample_levels(p[None].expand(3, -1), levels)[0] for p in peaks])
        return cls(levels, codebook.clamp(0, 1).cummax(1).values)


def resample_levels(codebook: Tensor, levels: int) -> Tensor:
    """``(3, levels)``: each row of ``codebook`` read as a curve over evenly spaced positions from 0 to 1 and
    sampled (linearly) at ``levels`` evenly spaced positions."""
    rows = copy.deepcopy(codebook).double()
    count = rows.shape[1]
    position = torch.linspace(0.0, count - 1.0, levels, dtype=torch.float64)
    low = position.floor().long().clamp(max=count - 1)
    high = (low + 1).clamp(max=count - 1)
    weight = position - low
    return (rows[:, low] * (1 - weight) + rows[:, high] * weight).float()
