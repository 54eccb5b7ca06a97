"""ISP stage: an image buffer of few levels (an ADC, or a buffer of few bits before a tone table)."""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Mapping, Sequence
from typing import ClassVar

import torch
from torch import Tensor

from camdegrade.effects._common import scalar
from camdegrade.effects._fitting import as_pairs
from camdegrade.effects.base import Effect, Pairs, check_range, evenly_spaced, register_effect, shown
from camdegrade.effects.isp.resolution import SCALES, Resolution
from camdegrade.functional.isp.quantization import (
    code_histogram,
    histogram_comb,
    histogram_peaks,
    quantize_image,
    skipped_runs,
    uniform_codebook,
)

__all__ = ["Quantization"]


@register_effect
class Quantization(Effect):
    """Every value snapped to the nearest of ``levels`` levels per channel (kernel
    :func:`~camdegrade.functional.isp.quantization.quantize_image`).

    The levels are the ``codebook``: evenly spaced for an ADC or a buffer of ``log2(levels)`` bits at the output;
    for a buffer quantized *before* a tone curve, the curve's values at the evenly spaced levels (the tone applied to
    already-quantized values: the output holds only those values, and posterises gradients). It sits in the ISP
    at the end of the ISP; a buffer quantized before the ISP's upscale is quantized on the grid of ``scale`` of the
    output's resolution (the error to its quantized self there upsampled and added: a ``resolution`` stage before
    it has already upscaled the content).

    Args:
        levels: the number of levels per channel, from 2 to 256 (256, the default with an even codebook: none).
        codebook: ``(3, levels)`` values in [0, 1], non-decreasing along each row (default: evenly spaced).
        scale: the resolution of the grid it quantizes on relative to the output's (1, the default: every pixel).

    Valid values (:meth:`check_values`): ``levels`` from 2 to 256; ``codebook`` in [0, 1], non-decreasing rows;
    ``scale`` from :attr:`MIN_SCALE` to 1.

    References:
        R. M. Gray, D. L. Neuhoff, "Quantization", IEEE Trans. Information Theory 44(6), 1998.
    """

    name = "quantization"
    stage = "isp"
    explains = ("comb",)
    fit_budget = 32
    MAX_LEVELS: ClassVar[int] = 256
    #: The most levels a fit or a rescaling gives (7 bits): a buffer of 8 bits before a tone table skips single
    #: codes only, which the profile's network already places within a level.
    MAX_FITTED_LEVELS: ClassVar[int] = 128
    #: The targets' code histogram must be combed (:func:`~camdegrade.functional.isp.quantization.histogram_comb`) at
    #: least this much for a fit to find levels (photos through a noisy camera: 0.03–0.09; a 5-bit buffer upscaled
    #: 2×: 0.12–0.19; not upscaled: 1.7; an 8-bit buffer through a contrast table: 0.2, docs/results.md).
    MIN_COMB: ClassVar[float] = 0.1
    MIN_SCALE: ClassVar[float] = Resolution.MIN_SCALE
    codebook: Tensor
    scale: Tensor

    def __init__(self, levels: int = 256, codebook: Tensor | None = None, scale: float = 1.0) -> None:
        super().__init__()
        if isinstance(levels, bool) or not isinstance(levels, int) or not 2 <= levels <= self.MAX_LEVELS:
            raise ValueError(f"levels must be an integer from 2 to {self.MAX_LEVELS}, got levels={levels!r}")
        values = uniform_codebook(levels) if codebook is None else torch.as_tensor(codebook, dtype=torch.float32)
        if tuple(values.shape) != (3, levels):
            raise ValueError(f"codebook must have shape (3, {levels}), got shape {tuple(values.shape)}")
        self.levels = levels
        check_range("scale", float(scale), self.MIN_SCALE, 1.0)
        self.register_buffer("codebook", values.detach().clone())
        self.register_buffer("scale", scalar(scale))
        self.check_values()

    def check_values(self) -> None:
        super().check_values()
        check_range("codebook", self.codebook, 0.0, 1.0)
        check_range("scale", self.scale, self.MIN_SCALE, 1.0)
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
        return type(self)(levels, resample_levels(self.codebook, levels), float(self.scale))

    def forward(self, image: Tensor, params: Mapping[str, Tensor] | None = None) -> Tensor:
        return quantize_image(image, self.codebook, float(self.scale))

    @classmethod
    def fit(cls, source: Pairs, target: Pairs) -> Quantization:
        """The levels the targets hold: per channel the peaks of the targets' 8-bit code histogram
        (:func:`~camdegrade.functional.isp.quantization.histogram_peaks`), continued at their end spacings to 0 and 1
        and as many per channel as the channel with the most (the others' top level repeated; at most
        :attr:`MAX_FITTED_LEVELS`, resampled).

        The neutral stage unless the targets' histogram is combed at least :attr:`MIN_COMB` by runs of more than one
        empty code (:func:`~camdegrade.functional.isp.quantization.skipped_runs`) or by none (an upscale after the
        buffer fills them): single empty codes are a tone table's on 8-bit values. The sources are not compared (a
        profile's noiseless output of flat walls combs its histogram as much). Recovers the 32 levels of a foreign
        camera's 5-bit buffer before its tone table exactly, and 31 of them when a 2× upscale follows
        (``tests/test_quantization.py``)."""
        pairs = as_pairs(source, target)
        histogram = sum(code_histogram(target) for _, target in pairs)
        comb, mean = histogram_comb(histogram)
        peaks = [histogram_peaks(row) for row in histogram]
        runs = torch.cat([skipped_runs(row) for row in histogram])
        single_skips = runs.numel() > 0 and float(runs.double().median()) < 2
        if float((comb / mean.clamp_min(1e-12)).mean()) < cls.MIN_COMB or single_skips or min(map(len, peaks)) < 2:
            return cls.neutral()
        levels = min(max(map(len, peaks)), cls.MAX_FITTED_LEVELS)
        codebook = torch.stack([_padded(p, levels) for p in peaks])
        return cls(levels, codebook.clamp(0, 1).cummax(1).values)

    @classmethod
    def fit_in_chain(
        cls,
        cleans: Sequence[Tensor],
        sources: Sequence[Tensor],
        captures: Sequence[Tensor],
        simulate_with: Callable[[Effect, Sequence[int]], list[Tensor]],
        *,
        seed: int = 0,
        calibration_pairs: int | None = None,
    ) -> Quantization:
        """:meth:`fit`'s levels on the grid (``scale`` 1, or one of the sensor resolutions
        :data:`~camdegrade.effects.isp.resolution.SCALES`) whose simulation through the profile, noise and all, combs
        the code histogram most as the captures do: a buffer quantized before a 2× upscale combs it by 0.12–0.19,
        the same levels on every pixel by 1.7 (the noise the profile simulates is what dithers it, so it is measured
        on simulations, not on the profile's noiseless output)."""
        fitted = cls.fit_within_budget(sources, captures)
        if fitted.levels == cls.MAX_LEVELS:
            return fitted
        chosen = evenly_spaced(range(len(cleans)), calibration_pairs or cls.fit_budget or len(cleans))
        comb, mean = histogram_comb(sum(code_histogram(captures[index]) for index in chosen))
        real = comb / mean.clamp_min(1e-12)
        grids = [cls(fitted.levels, fitted.codebook, scale) for scale in (1.0, *SCALES)]
        return min(grids, key=lambda grid: _comb_distance(simulate_with(grid, chosen), real))


def _comb_distance(images: Sequence[Tensor], real: Tensor) -> float:
    """How far the histogram comb of ``images`` is from ``real`` (per channel), mean over channels."""
    comb, mean = histogram_comb(sum(code_histogram(image) for image in images))
    return float((comb / mean.clamp_min(1e-12) - real).abs().mean())


def _padded(levels: Tensor, count: int) -> Tensor:
    """``levels`` (ascending) as ``count`` values: its top one repeated, or resampled when there are more."""
    if len(levels) >= count:
        return resample_levels(levels[None].expand(3, -1), count)[0]
    return torch.cat([levels, levels[-1:].expand(count - len(levels))]).float()


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
