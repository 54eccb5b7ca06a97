"""Which change to the profile closes the sim-to-real gap, and by how much.

Method (``docs/diagnosis.md``): the real pairs are split by scene into a calibration part and a held-out part. On
top of the profile, every change of four kinds is fitted on the calibration part and measured on the held-out part:

- **add** a registered effect the profile lacks (fitted against the profile's deterministic output, its strength
  refined for its place in the chain; noise calibrated by simulating the whole chain);
- **remove** a stage whose signature shows (the camera may not have it);
- **refit** a stage whose signature shows (too strong, too weak, the wrong shape): fitted anew with the stage left
  out, or the stage's own strength rescaled, whichever matches the calibration pairs better;
- **network**: a short fine-tune of the network through the stages after it, when a signature that no effect
  explains (8×8 blocks, the high-frequency transfer) is significant.

Each kind is one class in :mod:`camdegrade.diagnose.attribution.changes`; :mod:`camdegrade.diagnose.attribution.search`
fits and measures them. Changes are ranked by held-out gap. The best is accepted when its reduction is significant
(beyond three bootstrap standard errors and a minimum size); the other significant changes are then refitted on top of
it (combinations), until nothing helps or ``max_changes`` are accepted.

**Two findings.** A change to what the profile has (refit or remove a stage, fine-tune the network) fixes the
profile's own **misfit**; adding an effect names one the camera has and the profile **lacks**. A large misfit must
not hide a missing effect: the minimum reduction is relative to the gap left
(:meth:`~camdegrade.diagnose.heldout.Baseline.threshold_at`); while every accepted change is a misfit fix, *every*
candidate effect is refitted on top of them, not only the ones significant alone, and the missing effects are
ranked by their held-out closure there (:attr:`Attribution.missing_ranking`); and an effect the network fine-tune
would absorb is named first when fine-tuning on top of it ends closer to the camera (:func:`_named_first`).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from torch import Tensor

from camdegrade.diagnose.attribution.changes import KINDS, Change, check_kinds
from camdegrade.diagnose.attribution.search import Log, Round, Search
from camdegrade.diagnose.heldout import Baseline, HeldOut, ImagePairs
from camdegrade.effects import EFFECTS, check_effect_names
from camdegrade.measures import StatisticSet, family_gaps
from camdegrade.profile import CameraProfile

__all__ = ["MISFIT_KINDS", "Attribution", "attribute", "check_candidates", "keeping"]


@dataclass
class Attribution:
    """Everything the search found, for the report."""

    baseline: Baseline
    held: HeldOut
    singles: list[Change]
    combinations: list[Change]
    accepted: list[Change]
    final_profile: CameraProfile
    final_stats: StatisticSet
    final_sims: list[Tensor]
    noise_floor: float
    #: The clean images themselves measured as the simulation, when no change was accepted on a significant gap.
    identity: Change | None = None

    @property
    def misfit(self) -> list[Change]:
        """The accepted changes to what the profile has: its own misfit, fixed."""
        return [change for change in self.accepted if change.kind in MISFIT_KINDS]

    @property
    def missing(self) -> list[Change]:
        """The accepted effects the profile lacks."""
        return [change for change in self.accepted if change.kind not in MISFIT_KINDS]

    @property
    def missing_ranking(self) -> list[Change]:
        """Every candidate effect the profile lacks, ranked by held-out gap once the profile's own misfit is fixed:
        refitted on top of the misfit fixes accepted first, or alone when the first accepted change adds an
        effect (or nothing was accepted)."""
        leading = 0
        while leading < len(self.accepted) and self.accepted[leading].kind in MISFIT_KINDS:
            leading += 1
        if leading:
            on_top = [c for c in self.combinations if len(c.before) == leading and c.kind not in MISFIT_KINDS]
            if on_top:
                return sorted(on_top, key=lambda change: change.gap_after)
        return [change for change in self.singles if change.kind not in MISFIT_KINDS]

    @property
    def chosen(self) -> Change | None:
        return self.accepted[-1] if self.accepted else None

    @property
    def gap_after(self) -> float:
        return self.chosen.gap_after if self.chosen else self.baseline.gap

    @property
    def final_families(self) -> dict[str, float]:
        return family_gaps(self.held.real, self.final_stats, scale=self.held.scale)


#: Kinds of change that fix what the profile has (its own misfit); the rest add an effect it lacks.
MISFIT_KINDS = frozenset({"refit", "remove", "network"})


def check_candidates(candidates: Iterable[str] | str | None) -> list[str]:
    if candidates is None:
        return [name for name, effect in EFFECTS.items() if effect.candidate]
    return check_effect_names(candidates, "candidates")


def _named_first(
    search: Search, ranked: list[Change], accepted: list[Change], adds: list[str], say: Log
) -> tuple[list[Change], list[Change]]:
    """The changes to accept next from ``ranked`` (best first, the first significant), and the combinations tried
    to decide. The best, unless it is the network fine-tune and adding the best significant effect first, then
    fine-tuning on top, ends closer to the camera than the fine-tune alone: the fine-tune absorbs a colour cast as
    readily as it fixes its own grid, so an effect the camera has is named first. A stage refitted to hide the
    network's artefact fails that test (the fine-tune on top undoes what it compensated), so it is never preferred."""
    best = ranked[0]
    named = [change for change in ranked if change.significant and change.kind == "add"]
    if best.kind != "network" or not named:
        return [best], []
    first = named[0]
    say(f"on top of {' + '.join(change.label for change in [*accepted, first])} (before the network):")
    stats = first.stats if first.stats is not None else search.held.statistics(first.profile)[0]
    tried = search.changes(first.profile, stats, first.gap_after, [*accepted, first], {best.key}, adds, say)
    if tried and tried[0].significant and tried[0].gap_after < best.gap_after:
        return [first, tried[0]], tried
    return [best], tried


def _grow(
    search: Search, singles: list[Change], adds: list[str], max_changes: int, say: Log
) -> tuple[list[Change], list[Change]]:
    """Accept the best significant change, refit the other significant ones on top of it, and repeat while the best
    marginal reduction is significant (at most ``max_changes``). Returns the accepted chain and every combination."""
    accepted: list[Change] = []
    combinations: list[Change] = []
    if not (search.baseline.significant and singles and singles[0].significant):
        return accepted, combinations
    pool = {change.key for change in singles if change.significant}
    every_add = {("add", name) for name in adds} if "add" in search.kinds else set()
    chosen, tried = _named_first(search, singles, accepted, adds, say)
    while True:
        combinations.extend(tried)
        accepted.extend(chosen[: max_changes - len(accepted)])
        pool.difference_update(change.key for change in chosen)
        best = accepted[-1]
        misfit_only = all(change.kind in MISFIT_KINDS for change in accepted)
        allowed = pool | (every_add if misfit_only else set())  # a misfit may have hidden a missing effect
        if len(accepted) >= max_changes or not allowed:
            return accepted, combinations
        current: CameraProfile = best.profile  # type: ignore[assignment]  # significant ones were fitted
        stats = best.stats if best.stats is not None else search.held.statistics(current)[0]
        say(f"on top of {' + '.join(change.label for change in accepted)}:")
        extended = search.changes(current, stats, best.gap_after, list(accepted), allowed, adds, say)
        combinations.extend(extended)
        if not extended or not extended[0].significant:
            return accepted, combinations
        chosen, tried = _named_first(search, extended, accepted, adds, say)


def attribute(
    profile: CameraProfile,
    calibration: ImagePairs,
    held_out: ImagePairs,
    *,
    candidates: Iterable[str] | None = None,
    kinds: Iterable[str] = tuple(KINDS),
    max_changes: int = 3,
    seed: int = 0,
    log: Log | None = None,
) -> Attribution:
    """Rank the changes by held-out gap and accept the ones that close it (see the module docstring); ``kinds``
    says which kinds of change are tried."""
    say = log or (lambda message: None)
    adds = check_candidates(candidates)
    kinds = check_kinds(kinds)
    held = HeldOut.build(held_out, seed, "held-out")
    baseline = Baseline.measure(held, profile)
    say(f"held-out gap {baseline.gap:.2f} ± {baseline.gap_se:.2f} (profile against itself: {baseline.null:.2f})")
    search = Search(profile, calibration, held, baseline, seed, kinds)
    say("single changes:")
    singles = search.changes(profile, baseline.stats, baseline.gap, [], None, adds, say)
    accepted, combinations = _grow(search, singles, adds, max_changes, say)
    identity = None
    if baseline.significant and not accepted:  # nothing closes the gap: does the camera degrade less than the profile?
        identity = Round(search, profile, baseline.stats, baseline.gap, [], say).measured(
            "remove", "every stage and the network", CameraProfile(None, []), None
        )
    return Attribution(baseline, held, singles, combinations, *_final(profile, baseline, held, accepted), identity)


def keeping(result: Attribution, count: int, profile: CameraProfile) -> Attribution:
    """``result`` with only its first ``count`` accepted changes (``profile``: the one diagnosed); the changes after
    them are dropped from the accepted chain, the combinations tried stay."""
    accepted = result.accepted[:count]
    final = _final(profile, result.baseline, result.held, accepted)
    return Attribution(result.baseline, result.held, result.singles, result.combinations, *final, result.identity)


def _final(
    profile: CameraProfile, baseline: Baseline, held: HeldOut, accepted: list[Change]
) -> tuple[list[Change], CameraProfile, StatisticSet, list[Tensor], float]:
    """``(accepted, final profile, its held-out statistics, its held-out simulations, noise floor)``."""
    chosen = accepted[-1] if accepted else None
    final_profile = chosen.profile if chosen is not None and chosen.profile is not None else profile
    if chosen is not None and chosen.stats is not None:  # measured with the same draws when it was evaluated
        final_stats, final_sims = chosen.stats, final_profile.simulate(held.cleans, held.seed, stream=held.stream)
    else:
        final_stats, final_sims = baseline.stats, baseline.sims
    final_null, _ = held.statistics(final_profile, null=True)
    return accepted, final_profile, final_stats, final_sims, held.gap_between(final_null, final_stats)
