"""Which unmodelled effect causes the sim-to-real gap, and how far adding it closes the gap.

Method (``docs/diagnosis.md``): split the real pairs by scene into a calibration part and a held-out part. For
every effect in :data:`camdegrade.effects.EFFECTS`, fit it on the calibration part on top of the profile
(source: the profile's output without its random stages; target: the real capture), insert it into the chain
at its physical stage, simulate the held-out clean images and measure the held-out gap. Candidates are ranked by
gap reduction; the best is added when its reduction is significant (beyond three bootstrap standard errors and
a minimum size), then the next candidates are refitted on top of it (combinations), until nothing helps.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import torch
from torch import Tensor

from camdegrade._seeds import derive_seed
from camdegrade.diagnose.noise_fit import NoiseMoments, calibrate_noise
from camdegrade.diagnose.stats import (
    Scale,
    StatisticSet,
    bootstrap_indices,
    family_gaps,
    flat_mask,
    gap,
    gap_spread,
    measurement_scale,
)
from camdegrade.effects import EFFECTS, Effect, Noise
from camdegrade.errors import CamdegradeError
from camdegrade.fitting.pairset import simulate
from camdegrade.profile import CameraProfile

#: A reduction counts when it exceeds this many bootstrap standard errors ...
SIGNIFICANCE = 3.0
#: ... and this absolute size (gap units: one family off by one tau everywhere is 1) ...
MIN_REDUCTION = 0.5
#: ... and this share of the gap above the noise floor.
MIN_RELATIVE = 0.1
BOOTSTRAP_ROUNDS = 100
#: Calibration pairs on which the strength of each fitted candidate is refined.
REFINE_PAIRS = 12
#: Calibration pairs on which the noise candidate's level is calibrated by simulation (noise statistics only):
#: at most ``NOISE_PAIRS``, fewer for large images (about ``NOISE_PIXELS`` pixels), at least ``MIN_NOISE_PAIRS``.
NOISE_PAIRS = 32
NOISE_PIXELS = 1 << 20
MIN_NOISE_PAIRS = 8

ImagePairs = list[tuple[Tensor, Tensor]]
Log = Callable[[str], None]


@dataclass
class Candidate:
    """One candidate (an effect, or effects added in sequence) evaluated on the held-out pairs."""

    names: list[str]
    effects: list[Effect]
    profile: CameraProfile | None
    gap_after: float
    reduction: float
    reduction_se: float
    significant: bool = False
    families: dict[str, float] = field(default_factory=dict)
    error: str | None = None
    stats: StatisticSet | None = field(default=None, repr=False)


def effect_params(effect: Effect) -> dict[str, Any]:
    """An effect's fitted values (buffers) and options (config), JSON-serialisable."""
    values: dict[str, Any] = {}
    for key, value in effect.state_dict().items():
        values[key] = round(float(value), 6) if value.numel() == 1 else [round(v, 6) for v in value.flatten().tolist()]
    values.update(effect.config())
    return values


def add_effect(profile: CameraProfile, effect: Effect) -> CameraProfile:
    """``profile`` with ``effect`` inserted at its stage. A candidate is fitted against the profile's deterministic
    part, so where the profile has a stage of the same kind that this part leaves out (pure noise), the fitted
    effect is the whole of it and replaces that stage instead of adding to it."""
    chain = [e for e in profile.effects if not (type(e) is type(effect) and e.without_randomness() is None)]
    return profile.with_chain(chain).with_effects(effect)


def _every(items: Sequence[Any], limit: int) -> list[Any]:
    if len(items) <= limit:
        return list(items)
    step = len(items) / limit
    return [items[int(i * step)] for i in range(limit)]


def fit_candidate(name: str, sources: Sequence[Tensor], targets: Sequence[Tensor]) -> Effect:
    """Fit effect ``name`` so that ``targets ≈ effect(sources)``, on the pairs its fitter affords
    (:attr:`~camdegrade.effects.Effect.fit_budget`) with its options for such images."""
    cls = EFFECTS[name]
    if cls.fit_budget is not None:
        sources, targets = _every(sources, cls.fit_budget), _every(targets, cls.fit_budget)
    return cls.fit(list(sources), list(targets), **cls.fit_options(sources))


STRENGTHS = (0.6, 1.0, 1.6)


def refine_strength(
    effect: Effect, gap_of: Callable[[Effect], float], baseline: float, say: Callable[[str], None]
) -> tuple[Effect, float]:
    """Scale the fitted change so that the effect, at its place in the chain, best matches the calibration
    pairs: the fit itself sees the end of the chain, where later stages (tone, codec) have transformed it.
    A candidate that does not lower the calibration gap (``baseline``) at all is left as fitted."""
    tried = {1.0: gap_of(effect)}
    if tried[1.0] > baseline - MIN_REDUCTION:
        return effect, 1.0
    tried.update({strength: gap_of(effect.scaled(strength)) for strength in STRENGTHS if strength != 1.0})
    best = min(tried, key=tried.__getitem__)
    if best != 1.0:  # extend once past the edge of the bracket
        further = best * (best / 1.0)
        tried[further] = gap_of(effect.scaled(further))
    points = sorted(tried, key=tried.__getitem__)[:3]
    x = torch.tensor([math.log(p) for p in points], dtype=torch.float64)
    y = torch.tensor([tried[p] for p in points], dtype=torch.float64)
    design = torch.stack([x * x, x, torch.ones_like(x)], 1)
    try:
        a, b, _ = torch.linalg.solve(design, y).tolist()
    except RuntimeError:
        a = 0.0
    if a > 0:
        vertex = math.exp(min(max(-b / (2 * a), math.log(0.1)), math.log(10.0)))
        if all(abs(vertex - p) > 0.03 * p for p in tried):
            tried[vertex] = gap_of(effect.scaled(vertex))
    best = min(tried, key=tried.__getitem__)
    say(f"    {effect.name}: strength {best:.2f} (calibration gap {tried[best]:.2f}, at 1: {tried[1.0]:.2f})")
    return effect.scaled(best), best


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
        sims = simulate(profile, self.cleans, self.seed, stream=self.stream + (".null" if null else ""))
        return StatisticSet.measure(sims, self.cleans, self.masks), sims


@dataclass
class _NoiseCalibration:
    """Calibration pairs (every ``NOISE_PAIRS``-th) on which a noise candidate is calibrated by simulation."""

    index: list[int]
    cleans: list[Tensor]
    masks: list[Tensor]
    real: NoiseMoments
    seed: int

    @classmethod
    def build(cls, pairs: ImagePairs, seed: int) -> _NoiseCalibration:
        pixels = sum(clean.shape[-1] * clean.shape[-2] for clean, _ in pairs) / len(pairs)
        count = min(NOISE_PAIRS, max(MIN_NOISE_PAIRS, round(NOISE_PIXELS / pixels)))
        index = _every(list(range(len(pairs))), count)
        cleans = [pairs[i][0] for i in index]
        masks = [flat_mask(clean) for clean in cleans]
        real = NoiseMoments.measure([pairs[i][1] for i in index], cleans, masks)
        return cls(index, cleans, masks, real, seed)

    def measure(self, images: list[Tensor]) -> NoiseMoments:
        return NoiseMoments.measure(images, self.cleans, self.masks)

    def calibrate(self, effect: Noise, current: CameraProfile, sources: Sequence[Tensor], say: Log) -> Noise:
        """``effect`` rescaled so that ``current`` with it reproduces the real noise-level function."""
        return calibrate_noise(
            effect,
            lambda e: add_effect(current, e),
            lambda p: simulate(p, self.cleans, self.seed, stream="noise-moments"),
            self.real,
            self.measure([sources[i] for i in self.index]),
            self.measure,
            say=say,
        )


@dataclass
class Attribution:
    """Everything the ranking found, for the report."""

    gap_before: float
    gap_before_se: float
    base_families: dict[str, float]
    base_null: float
    base_null_families: dict[str, float]
    singles: list[Candidate]
    combinations: list[Candidate]
    chosen: Candidate | None
    final_profile: CameraProfile
    final_families: dict[str, float]
    noise_floor: float
    base_stats: StatisticSet
    final_stats: StatisticSet
    base_sims: list[Tensor]
    final_sims: list[Tensor]
    significant_gap: bool
    held_real: StatisticSet


@dataclass
class _Baseline:
    """The profile as given, measured on the held-out pairs: its gap, the gap's spread, the noise of the
    measurement (the profile against itself) and the smallest reduction that can count."""

    stats: StatisticSet
    sims: list[Tensor]
    gap: float
    gap_se: float
    null_families: dict[str, float]
    threshold: float
    significant: bool

    @classmethod
    def measure(cls, held: HeldOut, profile: CameraProfile) -> _Baseline:
        stats, sims = held.calibrate(profile)
        null_stats, _ = held.statistics(profile, null=True)
        before = held.gap(stats)
        null_families = family_gaps(null_stats, stats, scale=held.scale)
        spreads = gap_spread(held.real, [stats], held.indices, held.scale)
        se = float(spreads[:, 0].std())
        excess = max(0.0, before - sum(null_families.values()))
        threshold = max(MIN_REDUCTION, MIN_RELATIVE * excess)
        return cls(stats, sims, before, se, null_families, threshold, excess > max(SIGNIFICANCE * se, MIN_REDUCTION))

    @property
    def null(self) -> float:
        return sum(self.null_families.values())


class _Search:
    """Fits every candidate effect on the calibration pairs on top of a profile and measures it on the held-out
    pairs."""

    def __init__(self, profile: CameraProfile, calibration: ImagePairs, held: HeldOut, baseline: _Baseline, seed: int):
        self.profile = profile
        self.cleans = [clean for clean, _ in calibration]
        self.reals = [real for _, real in calibration]
        self.held = held
        self.baseline = baseline
        self.seed = seed
        self.check = HeldOut.build(_every(calibration, REFINE_PAIRS), seed, "strength-check")
        self.check_base, _ = self.check.calibrate(profile)
        self.moments = _NoiseCalibration.build(calibration, seed)

    def candidates(
        self,
        current: CameraProfile,
        stats: StatisticSet,
        gap_now: float,
        chain: list[Candidate],
        pool: list[str],
        say: Log,
    ) -> list[Candidate]:
        """Each effect of ``pool`` fitted on top of ``current`` (which ``chain`` built), best first."""
        sources = simulate(current, self.cleans, self.seed, stream="sources", deterministic=True)
        check_gap = self.check.gap(self.check_base if current is self.profile else self.check.statistics(current)[0])
        prefix_names = chain[-1].names if chain else []
        prefix_effects = chain[-1].effects if chain else []
        results = []
        for name in pool:
            try:
                effect = self._fitted(name, current, sources, check_gap, say)
            except (ValueError, RuntimeError, CamdegradeError) as error:
                say(f"  {name}: not fitted ({error})")
                failed = Candidate([*prefix_names, name], [*prefix_effects], None, gap_now, 0.0, 0.0, error=str(error))
                results.append(failed)
                continue
            names, effects = [*prefix_names, name], [*prefix_effects, effect]
            candidate = _evaluate(
                self.held, stats, gap_now, self.baseline.threshold, names, effects, add_effect(current, effect)
            )
            say(
                f"  {'+'.join(candidate.names)}: gap {candidate.gap_after:.2f} "
                f"(reduction {candidate.reduction:+.2f} ± {candidate.reduction_se:.2f})"
                f"{' *' if candidate.significant else ''}"
            )
            results.append(candidate)
        return sorted(results, key=lambda c: c.gap_after)

    def _fitted(self, name: str, current: CameraProfile, sources: list[Tensor], check_gap: float, say: Log) -> Effect:
        """Effect ``name`` fitted against ``current``'s deterministic output, its strength set for its place in the
        chain (noise: calibrated by simulated moments)."""
        effect = fit_candidate(name, sources, self.reals)
        if isinstance(effect, Noise):
            return self.moments.calibrate(effect, current, sources, say)
        check = self.check

        def calibration_gap(candidate: Effect) -> float:
            return check.gap(check.statistics(add_effect(current, candidate))[0])

        return refine_strength(effect, calibration_gap, check_gap, say)[0]


def _evaluate(
    held: HeldOut,
    base: StatisticSet,
    before: float,
    threshold: float,
    names: list[str],
    effects: list[Effect],
    profile: CameraProfile,
) -> Candidate:
    stats, _ = held.statistics(profile)
    after = held.gap(stats)
    reduction = before - after
    se, significant = float("nan"), False
    if reduction > threshold:  # otherwise it cannot be significant: skip the bootstrap
        spreads = gap_spread(held.real, [base, stats], held.indices, held.scale)
        se = float((spreads[:, 0] - spreads[:, 1]).std())
        significant = reduction > max(SIGNIFICANCE * se, threshold)
    families = family_gaps(held.real, stats, scale=held.scale)
    return Candidate(names, effects, profile, after, reduction, se, significant, families, stats=stats)


def _check_candidates(candidates: Iterable[str] | None) -> list[str]:
    names = list(EFFECTS) if candidates is None else list(candidates)
    unknown = [name for name in names if name not in EFFECTS]
    if unknown:
        raise ValueError(f"candidates must be effect names from {sorted(EFFECTS)}, got unknown {unknown}")
    return names


def _grow_chain(
    search: _Search, singles: list[Candidate], baseline: _Baseline, max_added: int, say: Log
) -> tuple[list[Candidate], list[Candidate]]:
    """Add the best significant candidate, refit the other significant ones on top of it, and repeat while the
    best marginal reduction is significant (at most ``max_added``). Returns the chain and every combination tried."""
    chain: list[Candidate] = []
    combinations: list[Candidate] = []
    if not (baseline.significant and singles and singles[0].significant):
        return chain, combinations
    pool = [c.names[-1] for c in singles if c.significant]
    best = singles[0]
    while True:
        chain.append(best)
        current: CameraProfile = best.profile  # type: ignore[assignment]  # significant ones were fitted
        stats = best.stats if best.stats is not None else search.held.statistics(current)[0]
        pool = [name for name in pool if name not in best.names]
        if len(chain) >= max_added or not pool:
            return chain, combinations
        say(f"on top of {'+'.join(best.names)}:")
        extended = search.candidates(current, stats, best.gap_after, chain, pool, say)
        combinations.extend(extended)
        if not extended or not extended[0].significant:
            return chain, combinations
        best = extended[0]


def attribute(
    profile: CameraProfile,
    calibration: ImagePairs,
    held_out: ImagePairs,
    *,
    candidates: Iterable[str] | None = None,
    max_added: int = 3,
    seed: int = 0,
    log: Log | None = None,
) -> Attribution:
    """Rank candidate effects by held-out gap reduction and choose the ones to add (see the module docstring)."""
    say = log or (lambda message: None)
    names = _check_candidates(candidates)
    held = HeldOut.build(held_out, seed, "held-out")
    baseline = _Baseline.measure(held, profile)
    say(f"held-out gap {baseline.gap:.2f} ± {baseline.gap_se:.2f} (profile against itself: {baseline.null:.2f})")
    search = _Search(profile, calibration, held, baseline, seed)
    say("single candidates:")
    singles = search.candidates(profile, baseline.stats, baseline.gap, [], names, say)
    chain, combinations = _grow_chain(search, singles, baseline, max_added, say)
    chosen = chain[-1] if chain else None
    final_profile = chosen.profile if chosen and chosen.profile is not None else profile
    if chosen is not None and chosen.stats is not None:  # measured with the same draws when it was evaluated
        final_stats, final_sims = chosen.stats, simulate(final_profile, held.cleans, seed, stream=held.stream)
    else:
        final_stats, final_sims = baseline.stats, baseline.sims
    final_null, _ = held.statistics(final_profile, null=True)
    return Attribution(
        gap_before=baseline.gap,
        gap_before_se=baseline.gap_se,
        base_families=family_gaps(held.real, baseline.stats, scale=held.scale),
        base_null=baseline.null,
        base_null_families=baseline.null_families,
        singles=singles,
        combinations=combinations,
        chosen=chosen,
        final_profile=final_profile,
        final_families=family_gaps(held.real, final_stats, scale=held.scale),
        noise_floor=held.gap_between(final_null, final_stats),
        base_stats=baseline.stats,
        final_stats=final_stats,
        base_sims=baseline.sims,
        final_sims=final_sims,
        significant_gap=baseline.significant,
        held_real=held.real,
    )
