"""The yardstick of the diagnosis: held-out pairs, their real statistics, and the profile as given measured on them
(its gap, the gap's spread, the noise of the measurement and the smallest reduction that can count)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

from torch import Tensor

from camdegrade._support.seeds import derive_seed
from camdegrade.functional.analysis.images import flat_mask
from camdegrade.measures import StatisticSet, bootstrap_indices, family_gaps, gap, gap_spread
from camdegrade.measures.gap import Scale, measurement_scale
from camdegrade.measures.traces.resampling import resampling_trace
from camdegrade.profile import CameraProfile

__all__ = ["BOOTSTRAP_ROUNDS", "MIN_REDUCTION", "MIN_RELATIVE", "SIGNIFICANCE", "Baseline", "HeldOut", "ImagePairs"]

#: A reduction counts when it exceeds this many bootstrap standard errors ...
SIGNIFICANCE = 3.0
#: ... and this absolute size (gap units: one family off by one tau everywhere is 1) ...
MIN_REDUCTION = 0.5
#: ... and this share of the gap above the noise floor.
MIN_RELATIVE = 0.1
BOOTSTRAP_ROUNDS = 100
ImagePairs = list[tuple[Tensor, Tensor]]


@dataclass
class HeldOut:
    """Pairs, their real statistics and the bootstrap resamples every gap on them is judged on.

    Simulations of the pairs draw from the seed stream ``stream`` (``stream + ".null"`` for the profile against
    itself), so every candidate is simulated with the same draws.
    """

    cleans: list[Tensor]
    reals: list[Tensor]
    masks: list[Tensor]
    real: StatisticSet
    indices: Tensor
    seed: int
    stream: str
    scale: Scale | None = None

    @classmethod
    def build(cls, pairs: ImagePairs, seed: int, stream: str) -> HeldOut:
        cleans = [clean for clean, _ in pairs]
        reals = [real for _, real in pairs]
        masks = [flat_mask(clean) for clean in cleans]
        real = StatisticSet.measure(reals, cleans, masks)
        indices = bootstrap_indices(len(cleans), BOOTSTRAP_ROUNDS, derive_seed(seed, stream, "bootstrap"))
        return cls(cleans, reals, masks, real, indices, seed, stream)

    @cached_property
    def real_period(self) -> int | None:
        """The upscale period the resampling trace finds in the captures, the clean images as the reference (None:
        none): a fact of the pairs, read once however many changes to the resampler are judged on them."""
        return resampling_trace(self.reals, self.cleans).period

    def calibrate(self, profile: CameraProfile) -> tuple[StatisticSet, list[Tensor]]:
        """Fix the yardstick (:func:`measurement_scale`) against ``profile``; return its statistics and
        simulations."""
        stats, sims = self.statistics(profile)
        self.scale = measurement_scale(self.real, stats, self.indices)
        return stats, sims

    def gap(self, stats: StatisticSet) -> float:
        return gap(self.real, stats, scale=self.scale)

    def gap_between(self, first: StatisticSet, second: StatisticSet) -> float:
        return gap(first, second, scale=self.scale)

    def statistics(self, profile: CameraProfile, *, null: bool = False) -> tuple[StatisticSet, list[Tensor]]:
        sims = profile.simulate(self.cleans, self.seed, stream=self.stream + (".null" if null else ""))
        return StatisticSet.measure(sims, self.cleans, self.masks), sims


@dataclass
class Baseline:
    """The profile as given, measured on the held-out pairs: its gap, the gap's spread, the noise of the
    measurement (the profile against itself) and the smallest reduction that can count."""

    stats: StatisticSet
    sims: list[Tensor]
    gap: float
    gap_se: float
    families: dict[str, float]
    null_families: dict[str, float]
    significant: bool

    @classmethod
    def measure(cls, held: HeldOut, profile: CameraProfile) -> Baseline:
        stats, sims = held.calibrate(profile)
        null_stats, _ = held.statistics(profile, null=True)
        before = held.gap(stats)
        null_families = family_gaps(null_stats, stats, scale=held.scale)
        spreads = gap_spread(held.real, [stats], held.indices, held.scale)
        se = float(spreads[:, 0].std())
        excess = max(0.0, before - sum(null_families.values()))
        return cls(
            stats,
            sims,
            before,
            se,
            family_gaps(held.real, stats, scale=held.scale),
            null_families,
            excess > max(SIGNIFICANCE * se, MIN_REDUCTION),
        )

    @property
    def null(self) -> float:
        return sum(self.null_families.values())

    def threshold_at(self, gap: float) -> float:
        """The smallest reduction that can count on top of a profile whose held-out gap is ``gap``: its share of
        *that* gap above the noise, not of the first one (after a misfit fix took most of the gap away, a missing
        effect's smaller reduction must still be able to count)."""
        return max(MIN_REDUCTION, MIN_RELATIVE * max(0.0, gap - self.null))

    def significant_axes(self) -> set[str]:
        """The signature families whose score stands out of their null band (as ``where`` marks them)."""
        return {name for name, score in self.families.items() if score > max(3 * self.null_families[name], 1.0)}
