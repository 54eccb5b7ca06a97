"""One round of the search: every change of the allowed kinds fitted on the calibration pairs on top of a profile,
measured on the held-out pairs, and ranked."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import cast

from torch import Tensor

from camdegrade.diagnose.attribution.changes import KINDS, AddEffect, Change, Plan, add_effect
from camdegrade.diagnose.attribution.evaluation import GapsByContent, evaluated
from camdegrade.diagnose.attribution.round_view import Made
from camdegrade.diagnose.attribution.signature import judge_cause
from camdegrade.diagnose.attribution.strength import refine_strength
from camdegrade.diagnose.heldout import SIGNIFICANCE, Baseline, HeldOut, ImagePairs
from camdegrade.effects import Effect
from camdegrade.effects.base import evenly_spaced
from camdegrade.errors import CamdegradeError
from camdegrade.fitting.in_chain import fit_stage_in_chain
from camdegrade.measures import StatisticSet, family_gaps, gap_spread
from camdegrade.profile import CameraProfile

__all__ = ["MIN_NOISE_PAIRS", "NOISE_PAIRS", "NOISE_PIXELS", "REFINE_PAIRS", "Log", "Round", "Search", "prefer_simpler"]

#: Calibration pairs on which the strength of each fitted change is refined.
REFINE_PAIRS = 12
#: Calibration pairs a noise stage is calibrated on by simulating the profile (about ``NOISE_PIXELS`` pixels).
NOISE_PAIRS = 32
NOISE_PIXELS = 1 << 20
MIN_NOISE_PAIRS = 8
Log = Callable[[str], None]


class Search:
    """Fits every change on the calibration pairs on top of a profile and measures it on the held-out pairs."""

    def __init__(
        self,
        profile: CameraProfile,
        calibration: ImagePairs,
        held: HeldOut,
        baseline: Baseline,
        seed: int,
        kinds: Sequence[str] = tuple(KINDS),
    ) -> None:
        self.profile = profile
        self.kinds = set(kinds)
        self.cleans = [clean for clean, _ in calibration]
        self.reals = [real for _, real in calibration]
        self.held = held
        self.baseline = baseline
        self.seed = seed
        self.check = HeldOut.build(evenly_spaced(calibration, REFINE_PAIRS), seed, "strength-check")
        self.check.calibrate(profile)
        self.check_gaps = GapsByContent(self.check)  # after calibrate: the gaps are on its scale
        pixels = sum(clean.shape[-1] * clean.shape[-2] for clean in self.cleans) / len(self.cleans)
        self.noise_pairs = min(NOISE_PAIRS, max(MIN_NOISE_PAIRS, round(NOISE_PIXELS / pixels)))

    def changes(
        self,
        current: CameraProfile,
        stats: StatisticSet,
        gap_now: float,
        before: list[Change],
        allowed: set[tuple[str, str]] | None,
        adds: Sequence[str],
        say: Log,
    ) -> list[Change]:
        """Every change on top of ``current`` (which ``before`` built), best first; ``allowed`` restricts them to
        those ``(kind, name)`` (None: all)."""
        round_ = Round(self, current, stats, gap_now, before, say)
        plans = [
            plan
            for plan in self.plans(current, adds)
            if plan.kind.kind in self.kinds and (allowed is None or (plan.kind.kind, plan.name) in allowed)
        ]
        results = evaluated(round_, plans)
        return prefer_simpler(sorted(results, key=lambda change: (change.not_a_cause, change.gap_after)))

    def plans(self, current: CameraProfile, adds: Sequence[str]) -> list[Plan]:
        """Every change worth trying on ``current``: candidates, then stage by stage, then the network."""
        axes = self.baseline.significant_axes()
        plans = [plan for name, kind in KINDS.items() if name != "add" for plan in kind.plans(current, adds, axes)]
        plans += cast(AddEffect, KINDS["add"]).placed_plans(current, adds, self.profile)
        return sorted(plans, key=_order)

    def fit_in_chain(self, profile: CameraProfile, kind: type[Effect]) -> Effect:
        """A stage of ``kind`` fitted at its place in ``profile`` (:meth:`Effect.fit_in_chain`)."""
        pairs = self.noise_pairs
        return fit_stage_in_chain(profile, kind, self.cleans, self.reals, seed=self.seed, calibration_pairs=pairs)


def _order(plan: Plan) -> tuple[int, ...]:
    return plan.order


@dataclass
class Round:
    """One round of the search: the profile changes are made to, and how each is measured."""

    search: Search
    current: CameraProfile
    stats: StatisticSet
    gap_now: float
    before: list[Change]
    say: Log
    _sources: list[Tensor] | None = None
    _check_gap: float | None = None

    def sources(self, profile: CameraProfile | None = None) -> list[Tensor]:
        """The deterministic output of ``profile`` (default: the current one) on the calibration images."""
        if profile is not None:
            return profile.simulate(self.search.cleans, self.search.seed, stream="sources", deterministic=True)
        if self._sources is None:
            self._sources = self.sources(self.current)
        return self._sources

    def check_gap(self, profile: CameraProfile | None = None) -> float:
        """The calibration check set's gap of ``profile`` (default: the current one)."""
        if profile is not None:
            return self.search.check_gaps(profile)
        if self._check_gap is None:
            self._check_gap = self.check_gap(self.current)
        return self._check_gap

    def evaluate(self, plan: Plan) -> Change:
        kind, name = plan.kind.kind, plan.name
        try:
            made: Made = plan.kind.make(self, plan.target)
        except (ValueError, RuntimeError, CamdegradeError) as error:
            self.say(f"  {kind} {name}: not fitted ({error})")
            return Change(kind, name, None, None, self.gap_now, before=list(self.before), error=str(error))
        profile, effect, description = made
        change = self.measured(kind, name, profile, effect)
        change.description = description
        judge_cause(change, self)
        marker = " *" if change.significant else ""
        said = f" — {change.description}" if change.description else ""
        self.say(f"  {change.label}: gap {change.gap_after:.2f} (reduction {change.reduction_text()}){marker}{said}")
        return change

    def measured(self, kind: str, name: str, profile: CameraProfile, effect: Effect | None) -> Change:
        """The change evaluated on the held-out pairs; its reduction is bootstrapped only when it could count."""
        held, baseline = self.search.held, self.search.baseline
        stats, _ = held.statistics(profile)
        after = held.gap(stats)
        reduction = self.gap_now - after
        se, significant = float("nan"), False
        threshold = baseline.threshold_at(self.gap_now)
        if reduction > threshold:  # otherwise it cannot be significant: skip the bootstrap
            spreads = gap_spread(held.real, [self.stats, stats], held.indices, held.scale)
            se = float((spreads[:, 0] - spreads[:, 1]).std())
            significant = reduction > max(SIGNIFICANCE * se, threshold)
        families = family_gaps(held.real, stats, scale=held.scale)
        return Change(
            kind,
            name,
            profile,
            effect,
            after,
            reduction,
            se,
            significant,
            families,
            before=list(self.before),
            stats=stats,
            reduction_needed=threshold,
        )

    def refined(self, effect: Effect, base: CameraProfile, *, explore: bool = False) -> tuple[Effect, float]:
        """``effect`` with its strength set for its place in ``base``'s chain, and its calibration gap; ``explore``
        tries other strengths even where the effect as it is does not help (an existing stage, rescaled)."""

        def calibration_gap(candidate: Effect) -> float:
            return self.check_gap(add_effect(base, candidate))

        baseline = None if explore else (self.check_gap() if base is self.current else self.check_gap(base))
        refined, _, calibrated_gap = refine_strength(effect, calibration_gap, baseline, self.say)
        return refined, calibrated_gap


def prefer_simpler(ranked: list[Change]) -> list[Change]:
    """``ranked`` (by held-out gap) with a simpler change of the same stage moved ahead of the best when it does as
    well (within half the best's reduction SE, or 2 % of its gap): removing vignetting, rather than refitting it to
    nothing. Not one that is not a cause (:mod:`camdegrade.diagnose.attribution.signature`)."""
    if len(ranked) < 2 or ranked[0].error is not None:
        return ranked
    best = ranked[0]
    tolerance = max(0.02 * best.gap_after, 0.5 * best.reduction_se if math.isfinite(best.reduction_se) else 0.0)
    simplicity = {kind: KINDS[kind].simplicity for kind in KINDS}
    rivals = [
        change
        for change in ranked[1:]
        if change.name == best.name
        and not change.not_a_cause
        and simplicity[change.kind] < simplicity[best.kind]
        and change.gap_after <= best.gap_after + tolerance
    ]
    if not rivals:
        return ranked
    simpler = min(rivals, key=lambda change: simplicity[change.kind])
    return [simpler, *[change for change in ranked if change is not simpler]]
