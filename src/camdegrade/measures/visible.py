"""What a person sees when simulated frames sit beside the camera's captures of the same scenes, judged against
its spread over the frames and said in words: the network's 4-pixel grid (:func:`compare_grid`, from
:func:`~camdegrade.measures.fidelity.grid_rms`) and texture too smooth or too sharp (:func:`compare_texture`, band
power per band of :data:`~camdegrade.measures.fidelity.BAND_EDGES`).

Each frame gives one value per look (simulation and capture of the same clean image); a look is **significant**
when the simulation differs from the camera beyond :data:`SIGNIFICANCE` standard errors of the mean per-frame log
ratio *and* by a size a person would notice (:data:`GRID_RATIO`, :data:`TEXTURE_LOG2`).

References:
    A. Odena, V. Dumoulin, C. Olah, "Deconvolution and Checkerboard Artifacts", Distill, 2016.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import torch
from torch import Tensor

from camdegrade.measures.fidelity import BAND_EDGES, GRID_PERIOD, MIN_BAND_POWER, band_power, grid_rms

__all__ = [
    "GRID_FLOOR",
    "GRID_MIN_LEVELS",
    "GRID_RATIO",
    "SIGNIFICANCE",
    "TEXTURE_LOG2",
    "GridComparison",
    "TextureComparison",
    "compare_grid",
    "compare_texture",
]

#: Standard errors (of the mean per-frame difference) a look must exceed to count.
SIGNIFICANCE = 3.0
#: The simulation's grid must be at least this many times the camera's to count ...
GRID_RATIO = 1.5
#: ... and at least this many 8-bit levels (RMS) above it: a grid below a tenth of a level is not seen.
GRID_MIN_LEVELS = 0.1
#: The least grid (levels) a frame is taken to have when the log ratio is formed.
GRID_FLOOR = 0.05
#: A band's power must differ by at least this much (log2; 0.25 is 19 %) to count.
TEXTURE_LOG2 = 0.25


def _frames(sims: Sequence[Tensor], reals: Sequence[Tensor]) -> None:
    if len(sims) != len(reals) or not sims:
        raise ValueError(f"sims and reals must be non-empty and as long, got {len(sims)} and {len(reals)}")


def _mean_se(values: Tensor) -> tuple[float, float]:
    """Mean and its standard error (NaN from fewer than two values)."""
    mean = float(values.mean()) if values.numel() else math.nan
    se = float(values.std() / math.sqrt(values.numel())) if values.numel() > 1 else math.nan
    return mean, se


@dataclass
class GridComparison:
    """The 4-pixel grid (:func:`~camdegrade.measures.fidelity.grid_rms`, 8-bit levels, mean over the frames) of the
    simulation and of the camera, their ratio, the standard error of the mean per-frame log ratio (``se``), and
    whether the simulation's grid is one a person sees (:data:`GRID_RATIO`, :data:`GRID_MIN_LEVELS`,
    :data:`SIGNIFICANCE`)."""

    sim: float
    real: float
    ratio: float | None
    se: float
    frames: int
    significant: bool

    @property
    def headline(self) -> str:
        """``"4-pixel grid 6.5× the camera's"``."""
        return f"{GRID_PERIOD}-pixel grid {self.ratio or math.inf:.1f}× the camera's"

    def describe(self) -> str:
        levels = f"RMS {self.sim:.2f} vs {self.real:.2f} levels on {self.frames} frames"
        if self.ratio is None:
            return f"4-pixel grid not measurable: the captures have none at all ({levels})"
        if self.significant:
            return f"the simulation carries a {self.headline} ({levels})"
        return f"no {GRID_PERIOD}-pixel grid beyond the camera's: {self.ratio:.2f}× ({levels})"

    def to_dict(self) -> dict:
        return {key: (round(value, 4) if isinstance(value, float) else value) for key, value in asdict(self).items()}


def compare_grid(sims: Sequence[Tensor], reals: Sequence[Tensor]) -> GridComparison:
    """The grid of the simulated frames against the captures of the same scenes (each ``(3, H, W)`` in [0, 1]).

    The spread is that of the per-frame log ratio (a network's grid scales with the frame's texture, so frames
    differ more in level than in ratio); a frame's grid is floored at :data:`GRID_FLOOR` levels (a flat frame has
    none to divide by)."""
    _frames(sims, reals)
    sim = torch.tensor([grid_rms(image) for image in sims], dtype=torch.float64)
    real = torch.tensor([grid_rms(image) for image in reals], dtype=torch.float64)
    log_ratio, se = _mean_se(torch.log(sim.clamp_min(GRID_FLOOR) / real.clamp_min(GRID_FLOOR)))
    ratio = float(sim.mean() / real.mean()) if float(real.mean()) > 0 else None
    seen = ratio is not None and ratio >= GRID_RATIO and float(sim.mean() - real.mean()) >= GRID_MIN_LEVELS
    significant = seen and (math.isnan(se) or log_ratio > SIGNIFICANCE * se)
    return GridComparison(float(sim.mean()), float(real.mean()), ratio, se, len(sims), significant)


@dataclass
class TextureComparison:
    """Per band of :data:`BAND_EDGES`: the mean over frames of ``log2(power(sim) / power(real))`` (``None``: no
    frame has power in the band), its standard error, and whether it is a difference a person sees (beyond
    :data:`TEXTURE_LOG2` and :data:`SIGNIFICANCE` standard errors)."""

    log2: list[float | None]
    se: list[float | None]
    bands_significant: list[bool]
    frames: int

    @property
    def significant(self) -> bool:
        """Whether any band differs by a size a person sees."""
        return any(self.bands_significant)

    @property
    def worst(self) -> float:
        """The largest ``|log2|`` of a band that differs by a size a person sees (0: none does)."""
        seen = [abs(value) for value, shown in zip(self.log2, self.bands_significant) if shown and value is not None]
        return max(seen, default=0.0)

    def runs(self) -> list[tuple[int, int, float]]:
        """``(first band, last band, mean log2)`` of every run of adjacent significant bands of one sign, the
        largest first."""
        out: list[tuple[int, int, float]] = []
        band = 0
        while band < len(self.log2):
            if not self.bands_significant[band]:
                band += 1
                continue
            last = band
            sign = math.copysign(1.0, self.log2[band])  # type: ignore[arg-type]
            while (
                last + 1 < len(self.log2)
                and self.bands_significant[last + 1]
                and math.copysign(1.0, self.log2[last + 1]) == sign  # type: ignore[arg-type]
            ):
                last += 1
            values = [v for v in self.log2[band : last + 1] if v is not None]
            out.append((band, last, sum(values) / len(values)))
            band = last + 1
        return sorted(out, key=lambda run: -abs(run[2]))

    @property
    def direction(self) -> str | None:
        """``"smooth"`` or ``"sharp"`` for the largest significant difference, None when there is none."""
        runs = self.runs()
        return None if not runs else ("smooth" if runs[0][2] < 0 else "sharp")

    def describe(self) -> str:
        runs = self.runs()
        if not runs:
            measured = [(abs(v), v, k) for k, v in enumerate(self.log2) if v is not None]
            if not measured:
                return "texture not measurable: the frames have no power in any band"
            _, value, band = max(measured)
            return (
                f"texture within the camera's in every band (largest: {value:+.2f} log2 at "
                f"{BAND_EDGES[band]:g}–{BAND_EDGES[band + 1]:g} cycles/px)"
            )
        parts = []
        for first, last, value in runs:
            word = "too smooth" if value < 0 else "too sharp (or noisy)"
            parts.append(
                f"texture {word} at {BAND_EDGES[first]:g}–{BAND_EDGES[last + 1]:g} cycles/px by {abs(value):.2f} "
                f"log2 (power {2**value:.2f}× the camera's)"
            )
        return "; ".join(parts) + f" on {self.frames} frames"

    def to_dict(self) -> dict:
        def rounded(values: list[float | None]) -> list[float | None]:
            return [None if v is None or not math.isfinite(v) else round(v, 4) for v in values]

        return {
            "log2": rounded(self.log2),
            "se": rounded(self.se),
            "significant": list(self.bands_significant),
            "band_edges": list(BAND_EDGES),
            "frames": self.frames,
        }


def compare_texture(sims: Sequence[Tensor], reals: Sequence[Tensor]) -> TextureComparison:
    """The band power of the simulated frames against the captures of the same scenes (frames of any size)."""
    _frames(sims, reals)
    sim = torch.stack([band_power(image)[0] for image in sims])
    real = torch.stack([band_power(image)[0] for image in reals])
    measurable = (sim >= MIN_BAND_POWER) & (real >= MIN_BAND_POWER)
    ratios = torch.log2(sim.clamp_min(MIN_BAND_POWER) / real.clamp_min(MIN_BAND_POWER))
    log2, errors, significant = [], [], []
    for band in range(ratios.shape[1]):
        mean, se = _mean_se(ratios[measurable[:, band], band])
        log2.append(None if math.isnan(mean) else mean)
        errors.append(None if math.isnan(se) else se)
        significant.append(
            not math.isnan(mean) and abs(mean) >= TEXTURE_LOG2 and (math.isnan(se) or abs(mean) > SIGNIFICANCE * se)
        )
    return TextureComparison(log2, errors, significant, len(sims))
