"""The noise families, all measured on the image's own noise where the clean image is flat
(:class:`~camdegrade.functional.analysis.noise.NoiseSums`, computed once per pair): ``noise`` (its level),
``noise_correlation`` (its structure) and ``banding`` (its row and column means).

Noise levels are compared as log std: a noise level is a scale, and a 1-level miss matters at std 2 and not at
std 30. These families compare noise levels, not noise samples, which is what makes the gap fair to stochastic
effects: a correct noise stage does not increase it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
from torch import Tensor

from camdegrade.functional.analysis.noise import LAGS, MIN_LINES, MIN_PIXELS, NoiseSums
from camdegrade.measures._common import ratio
from camdegrade.measures.base import MeasuredPair, PairedFamily, register_family

if TYPE_CHECKING:
    from camdegrade.effects import Effect
    from camdegrade.measures.statistics import StatisticSet

__all__ = [
    "LINE_FLOOR",
    "MIN_ENERGY",
    "NOISE_BINS",
    "NOISE_FLOOR",
    "Banding",
    "NoiseCorrelation",
    "NoiseLevel",
    "flat_pixels",
    "noise_stage_text",
]

NOISE_BINS = 8
#: Noise levels are compared as ``log sqrt(std² + floor²)``; the floor (0.5 level, above 8-bit quantisation's
#: 0.29) keeps a missing noise stage finite.
NOISE_FLOOR = 0.5
#: Line means are a small part of the noise (0.3 levels on real captures): their floor is lower.
LINE_FLOOR = 0.1
#: Residual energy per flat pixel (levels²) below which there is no noise to correlate: 8-bit quantisation alone
#: gives 0.08; below this the residual is float rounding of a noise-free image, and its correlations mean nothing.
MIN_ENERGY = 1e-6
_CHANNELS = ("R", "G", "B")
_CHANNEL_PAIRS = ((0, 1), (0, 2), (1, 2))


def _noise_sums(pair: MeasuredPair) -> dict[str, tuple[Tensor, Tensor]]:
    """The three families' sums from one :class:`NoiseSums` of the pair."""
    sums = NoiseSums.measure(pair.image, pair.clean, pair.mask)
    products, first, second, _ = sums.lag.unbind(-1)
    cross = sums.cross
    correlation_num = torch.cat([products.flatten(), torch.stack([cross[i, j] for i, j in _CHANNEL_PAIRS])])
    energies = torch.cat(
        [((first + second) / 2).flatten(), torch.stack([(cross[i, i] + cross[j, j]) / 2 for i, j in _CHANNEL_PAIRS])]
    )
    pixels = sums.count.sum(1).max()
    return {
        NoiseLevel.name: (sums.square.flatten().float(), sums.count.flatten().float()),
        NoiseCorrelation.name: (
            torch.cat([correlation_num, pixels[None]]).float(),
            torch.cat([energies, torch.ones(1, dtype=energies.dtype)]).float(),
        ),
        Banding.name: (sums.lines[..., 0].flatten().float(), sums.lines[..., 2].flatten().float()),
    }


def flat_pixels(real_set: StatisticSet) -> int:
    """Pixels (per channel, the most any channel has) the noise families rest on, over every pair."""
    return int(real_set.sums[NoiseLevel.name][1].double().sum(0).reshape(3, -1).sum(1).max())


def _lines(real_set: StatisticSet) -> tuple[int, int]:
    """Rows and columns (channel 0) the banding family rests on, over every pair."""
    counts = real_set.sums[Banding.name][1].double().sum(0).reshape(2, 3)
    return int(counts[0, 0]), int(counts[1, 0])


@register_family
class NoiseLevel(PairedFamily):
    """Std of ``x`` minus its 17×17 mean where ``c`` is flat in absolute terms, in 8 bins of clean value."""

    name = "noise"
    tau = 0.05
    unit = "8-bit levels (std); compared as log std, tau 5 %"
    description = "std of x minus its 17×17 mean where c is flat, 8 bins of clean value, compared as log std"

    def measure(self, pair: MeasuredPair) -> tuple[Tensor, Tensor]:
        return pair.shared(_noise_sums)[self.name]

    def reduce(self, num: Tensor, den: Tensor) -> Tensor:
        """Sums of squared residuals (levels²) and flat-pixel counts → std in levels; NaN below MIN_PIXELS."""
        return torch.where(den >= MIN_PIXELS, num / den.clamp_min(1), torch.nan).sqrt()

    def compare(self, values: Tensor) -> Tensor:
        return 0.5 * torch.log(values.pow(2) + NOISE_FLOOR**2)

    def describe(self, real: Tensor, sim: Tensor, real_set: StatisticSet) -> str:
        pixels = flat_pixels(real_set)
        r = torch.nanmean(real.reshape(3, NOISE_BINS), 1)
        if not bool(torch.isfinite(r).any()):
            return f"noise not measurable: {pixels:,} pixels where the clean image is flat (a bin needs {MIN_PIXELS:,})"
        s = torch.nanmean(sim.reshape(3, NOISE_BINS), 1)
        return (
            f"noise std on {pixels:,} flat pixels (levels): real "
            + ", ".join(f"{c} {a:.2f}" for c, a in zip(_CHANNELS, r.tolist(), strict=True))
            + " vs sim "
            + ", ".join(f"{c} {b:.2f}" for c, b in zip(_CHANNELS, s.tolist(), strict=True))
        )

    @classmethod
    def describes(cls, effect: type[Effect]) -> bool:
        """Whether this family's numbers say what a stage of ``effect`` does (it explains the noise signature)."""
        return cls.name in effect.explains


@register_family
class NoiseCorrelation(PairedFamily):
    """That residual's correlation at lags 1, 2 (horizontal, vertical) per channel, and between the channels."""

    name = "noise_correlation"
    tau = 0.05
    unit = "correlation"
    description = "the noise residual's correlation at lags 1, 2 per channel, and between channels (chroma noise)"
    pixel_pattern = True

    def measure(self, pair: MeasuredPair) -> tuple[Tensor, Tensor]:
        return pair.shared(_noise_sums)[self.name]

    def reduce(self, num: Tensor, den: Tensor) -> Tensor:
        """Products and energies → correlations (lags, then channel pairs); all NaN where the flat pixels behind
        them (the last component) are too few, and NaN where there is no noise (:data:`MIN_ENERGY`)."""
        values = ratio(num[..., :-1], den[..., :-1])
        noisy = den[..., :-1] > MIN_ENERGY * num[..., -1:]
        return torch.where((num[..., -1:] >= MIN_PIXELS) & noisy, values, torch.nan)

    def describe(self, real: Tensor, sim: Tensor, real_set: StatisticSet) -> str:
        pixels = flat_pixels(real_set)
        if not bool(torch.isfinite(real).any()):
            if pixels >= MIN_PIXELS:
                return f"noise correlation not measurable: the captures hold no noise on {pixels:,} flat pixels"
            return f"noise correlation not measurable: {pixels:,} flat pixels (needs {MIN_PIXELS:,})"

        def lag1(values: Tensor) -> tuple[float, float]:
            lags = values[: 2 * len(LAGS) * 3].reshape(2, len(LAGS), 3)
            return float(lags[0, 0].mean()), float(lags[1, 0].mean())

        def chroma(values: Tensor) -> float:
            return float(values[2 * len(LAGS) * 3 :].mean())

        (rh, rv), (sh, sv) = lag1(real), lag1(sim)
        return (
            f"noise correlation with the next pixel: real h {rh:.2f} v {rv:.2f} vs sim h {sh:.2f} v {sv:.2f}; "
            f"between channels real {chroma(real):.2f} vs sim {chroma(sim):.2f} ({pixels:,} flat pixels)"
        )


@register_family
class Banding(PairedFamily):
    """Std of the residual's per-row and per-column means (flat pixels), per channel, compared as log std."""

    name = "banding"
    tau = 0.05
    unit = "8-bit levels (std of line means); compared as log std"
    description = "std of the noise residual's per-row and per-column means on flat pixels, compared as log std"

    def measure(self, pair: MeasuredPair) -> tuple[Tensor, Tensor]:
        return pair.shared(_noise_sums)[self.name]

    def reduce(self, num: Tensor, den: Tensor) -> Tensor:
        """Sums of squared line means and line counts → std in levels; NaN below MIN_LINES lines."""
        return torch.where(den >= MIN_LINES, num / den.clamp_min(1), torch.nan).sqrt()

    def compare(self, values: Tensor) -> Tensor:
        return 0.5 * torch.log(values.pow(2) + LINE_FLOOR**2)

    def describe(self, real: Tensor, sim: Tensor, real_set: StatisticSet) -> str:
        rows, columns = _lines(real_set)
        if not bool(torch.isfinite(real).any()):
            return f"banding not measurable: {rows} rows, {columns} columns with enough flat pixels (needs {MIN_LINES})"
        r, s = real.reshape(2, 3).nanmean(1), sim.reshape(2, 3).nanmean(1)
        return (
            f"std of row means real {r[0]:.2f} vs sim {s[0]:.2f} levels, of column means real {r[1]:.2f} vs sim "
            f"{s[1]:.2f} ({rows:,} rows, {columns:,} columns on flat pixels)"
        )


def noise_stage_text(name: str, real: StatisticSet, sim: StatisticSet) -> str:
    """What a noise stage does wrong, from the pooled noise and banding values of the flat pixels: "noise stage is
    4.6× the camera's noise and banded (row means 9.5× the camera's)"."""
    real_values, sim_values = real.values(), sim.values()
    real_std, sim_std = (float(torch.nanmean(v[NoiseLevel.name])) for v in (real_values, sim_values))
    if real_std == real_std and real_std**2 <= MIN_ENERGY:  # measured (not NaN), and nothing there
        return f"{name} stage adds noise where the camera shows none ({sim_std:.2f} levels on its flat pixels)"
    text = f"{name} stage is {sim_std / real_std:.1f}× the camera's noise" if real_std > 0 else f"{name} stage"
    real_lines, sim_lines = (float(torch.nanmean(v[Banding.name][:3])) for v in (real_values, sim_values))
    if real_lines > 0 and sim_lines / real_lines > 1.5:
        text += f" and banded (row means {sim_lines / real_lines:.1f}× the camera's)"
    return text
