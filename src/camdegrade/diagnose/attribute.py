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

Changes are ranked by held-out gap. The best is accepted when its reduction is significant (beyond three bootstrap
standard errors and a minimum size); the other significant changes are then refitted on top of it (combinations),
until nothing helps or ``max_changes`` are accepted.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import torch
from torch import Tensor

from camdegrade._seeds import derive_seed
from camdegrade.effects import EFFECTS, Effect, check_effect_names
from camdegrade.effects.base import evenly_spaced
from camdegrade.errors import CamdegradeError
from camdegrade.fitting.finetune import finetune_network
from camdegrade.fitting.noise import fit_stage_in_chain, replace_stage
from camdegrade.fitting.pairset import simulate
from camdegrade.functional.analysis import flat_mask
from camdegrade.measures import FAMILIES, StatisticSet, bootstrap_indices, family_gaps, gap, gap_spread
from camdegrade.measures.gap import Scale, measurement_scale
from camdegrade.measures.noise import NoiseLevel, noise_stage_text
from camdegrade.profile import CameraProfile

#: A reduction counts when it exceeds this many bootstrap standard errors ...
SIGNIFICANCE = 3.0
#: ... and this absolute size (gap units: one family off by one tau everywhere is 1) ...
MIN_REDUCTION = 0.5
#: ... and this share of the gap above the noise floor.
MIN_RELATIVE = 0.1
BOOTSTRAP_ROUNDS = 100
#: Calibration pairs on which the strength of each fitted change is refined.
REFINE_PAIRS = 12
#: Calibration pairs a noise stage is calibrated on by simulating the profile (about ``NOISE_PIXELS`` pixels).
NOISE_PAIRS = 32
NOISE_PIXELS = 1 << 20
MIN_NOISE_PAIRS = 8
STRENGTHS = (0.6, 1.0, 1.6)

Kind = Literal["add", "remove", "refit", "network"]
KINDS: tuple[str, ...] = ("add", "remove", "refit", "network")
ImagePairs = list[tuple[Tensor, Tensor]]
Log = Callable[[str], None]


@dataclass
class Change:
    """One change to the profile (after the changes accepted before it), evaluated on the held-out pairs."""

    kind: Kind
    name: str
    profile: CameraProfile | None
    effect: Effect | None
    gap_after: float
    reduction: float = 0.0
    reduction_se: float = float("nan")
    significant: bool = False
    families: dict[str, float] = field(default_factory=dict)
    description: str = ""
    before: list[Change] = field(default_factory=list)
    error: str | None = None
    stats: StatisticSet | None = field(default=None, repr=False)

    @property
    def label(self) -> str:
        return f"{self.kind} {self.name}"

    @property
    def key(self) -> tuple[str, str]:
        return self.kind, self.name

    @property
    def chain(self) -> list[Change]:
        """This change after the ones accepted before it."""
        return [*self.before, self]


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
    effect is the whole of it and replaces that stage instead of adding to it (:func:`replace_stage`)."""
    return replace_stage(profile, effect)


def fit_candidate(name: str, sources: Sequence[Tensor], targets: Sequence[Tensor]) -> Effect:
    """Fit effect ``name`` so that ``targets ≈ effect(sources)`` (:meth:`Effect.fit_within_budget`)."""
    return EFFECTS[name].fit_within_budget(sources, targets)


def refine_strength(
    effect: Effect, gap_of: Callable[[Effect], float], baseline: float | None, say: Log
) -> tuple[Effect, float, float]:
    """Scale the fitted change so that the effect, at its place in the chain, best matches the calibration
    pairs: the fit itself sees the end of the chain, where later stages (tone, codec) have transformed it.
    A candidate that does not lower the calibration gap (``baseline``) at all is left as fitted; with ``baseline``
    None every strength is explored. Returns the effect, its strength and its calibration gap."""
    tried = {1.0: gap_of(effect)}
    if baseline is not None and tried[1.0] > baseline - MIN_REDUCTION:
        return effect, 1.0, tried[1.0]
    tried.update({strength: gap_of(effect.scaled(strength)) for strength in STRENGTHS if strength != 1.0})
    best = min(tried, key=tried.__getitem__)
    if best != 1.0:  # extend once past the edge of the bracket
        further = best * best
        tried[further] = gap_of(effect.scaled(further))
    vertex = _parabola_vertex(tried)
    if vertex is not None and all(abs(vertex - p) > 0.03 * p for p in tried):
        tried[vertex] = gap_of(effect.scaled(vertex))
    best = min(tried, key=tried.__getitem__)
    say(f"    {effect.name}: strength {best:.2f} (calibration gap {tried[best]:.2f}, at 1: {tried[1.0]:.2f})")
    return effect.scaled(best), best, tried[best]


def _parabola_vertex(tried: dict[float, float]) -> float | None:
    """The minimum, in log strength, of the parabola through the three best strengths tried (within 0.1–10)."""
    points = sorted(tried, key=tried.__getitem__)[:3]
    x = torch.tensor([math.log(p) for p in points], dtype=torch.float64)
    y = torch.tensor([tried[p] for p in points], dtype=torch.float64)
    try:
        a, b, _ = torch.linalg.solve(torch.stack([x * x, x, torch.ones_like(x)], 1), y).tolist()
    except RuntimeError:
        return None
    if a <= 0:
        return None
    return math.exp(min(max(-b / (2 * a), math.log(0.1)), math.log(10.0)))


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
class Baseline:
    """The profile as given, measured on the held-out pairs: its gap, the gap's spread, the noise of the
    measurement (the profile against itself) and the smallest reduction that can count."""

    stats: StatisticSet
    sims: list[Tensor]
    gap: float
    gap_se: float
    families: dict[str, float]
    null_families: dict[str, float]
    threshold: float
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
            max(MIN_REDUCTION, MIN_RELATIVE * excess),
            excess > max(SIGNIFICANCE * se, MIN_REDUCTION),
        )

    @property
    def null(self) -> float:
        return sum(self.null_families.values())

    def significant_axes(self) -> set[str]:
        """The signature families whose score stands out of their null band (as ``where`` marks them)."""
        return {name for name, score in self.families.items() if score > max(3 * self.null_families[name], 1.0)}


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

    @property
    def chosen(self) -> Change | None:
        return self.accepted[-1] if self.accepted else None

    @property
    def gap_after(self) -> float:
        return self.chosen.gap_after if self.chosen else self.baseline.gap

    @property
    def final_families(self) -> dict[str, float]:
        return family_gaps(self.held.real, self.final_stats, scale=self.held.scale)


class Search:
    """Fits every change on the calibration pairs on top of a profile and measures it on the held-out pairs."""

    def __init__(
        self,
        profile: CameraProfile,
        calibration: ImagePairs,
        held: HeldOut,
        baseline: Baseline,
        seed: int,
        kinds: Sequence[str] = KINDS,
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
        context = _Context(self, current, stats, gap_now, before, say)
        plans = self._plans(current, adds)
        results = []
        for kind, name, make in plans:
            if kind not in self.kinds or (allowed is not None and (kind, name) not in allowed):
                continue
            results.append(context.evaluate(kind, name, make))
        return _prefer_simpler(sorted(results, key=lambda change: change.gap_after))

    def _plans(self, current: CameraProfile, adds: Sequence[str]) -> list[tuple[Kind, str, Callable]]:
        """``(kind, name, make)`` for each change worth trying; ``make(context)`` returns ``(profile, effect,
        description)``."""
        present = {type(effect) for effect in current.effects}
        plans: list[tuple[Kind, str, Callable]] = [
            ("add", name, _adder(name)) for name in adds if EFFECTS[name] not in present
        ]
        axes = self.baseline.significant_axes()
        for index, stage in enumerate(current.effects):
            if set(stage.explains) & axes:  # a stage can be wrong only where the gap shows its signature
                plans.append(("remove", stage.name, _remover(index)))
                plans.append(("refit", stage.name, _refitter(index)))
        # Families the network's own artefacts show (``network_fault``) send it to a fine-tune when significant;
        # effects explain them too (JPEG blocks, blur), so their candidates are tried beside it.
        if current.network is not None and any(FAMILIES[axis].network_fault for axis in axes):
            plans.append(("network", "network", _network_refit))
        return plans

    def fit_in_chain(self, profile: CameraProfile, kind: type[Effect]) -> Effect:
        """A stage of ``kind`` fitted at its place in ``profile`` (:meth:`Effect.fit_in_chain`)."""
        pairs = self.noise_pairs
        return fit_stage_in_chain(profile, kind, self.cleans, self.reals, seed=self.seed, calibration_pairs=pairs)


@dataclass
class _Context:
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
            return simulate(profile, self.search.cleans, self.search.seed, stream="sources", deterministic=True)
        if self._sources is None:
            self._sources = self.sources(self.current)
        return self._sources

    def check_gap(self, profile: CameraProfile | None = None) -> float:
        """The calibration check set's gap of ``profile`` (default: the current one)."""
        check = self.search.check
        if profile is not None:
            return check.gap(check.statistics(profile)[0])
        if self._check_gap is None:
            self._check_gap = self.check_gap(self.current)
        return self._check_gap

    def evaluate(self, kind: Kind, name: str, make: Callable) -> Change:
        try:
            profile, effect, description = make(self)
        except (ValueError, RuntimeError, CamdegradeError) as error:
            self.say(f"  {kind} {name}: not fitted ({error})")
            return Change(kind, name, None, None, self.gap_now, before=list(self.before), error=str(error))
        change = _measured(self.search, self.stats, self.gap_now, kind, name, profile, effect, self.before)
        change.description = description
        marker = " *" if change.significant else ""
        said = f" — {description}" if description else ""
        self.say(
            f"  {change.label}: gap {change.gap_after:.2f} (reduction {change.reduction:+.2f} ± "
            f"{change.reduction_se:.2f}){marker}{said}"
        )
        return change

    def refined(self, effect: Effect, base: CameraProfile, *, explore: bool = False) -> tuple[Effect, float]:
        """``effect`` with its strength set for its place in ``base``'s chain, and its calibration gap; ``explore``
        tries other strengths even where the effect as it is does not help (an existing stage, rescaled)."""

        def calibration_gap(candidate: Effect) -> float:
            return self.check_gap(add_effect(base, candidate))

        baseline = None if explore else (self.check_gap() if base is self.current else self.check_gap(base))
        refined, _, calibrated_gap = refine_strength(effect, calibration_gap, baseline, self.say)
        return refined, calibrated_gap


def _adder(name: str) -> Callable[[_Context], tuple[CameraProfile, Effect, str]]:
    def make(context: _Context) -> tuple[CameraProfile, Effect, str]:
        cls = EFFECTS[name]
        if cls.draws_only_noise():
            effect = context.search.fit_in_chain(context.current, cls)
        else:
            effect, _ = context.refined(fit_candidate(name, context.sources(), context.search.reals), context.current)
        return add_effect(context.current, effect), effect, f"adds {name}"

    return make


def _remover(index: int) -> Callable[[_Context], tuple[CameraProfile, None, str]]:
    def make(context: _Context) -> tuple[CameraProfile, None, str]:
        stage = context.current.effects[index]
        chain = [e for i, e in enumerate(context.current.effects) if i != index]
        if NoiseLevel.describes(type(stage)):  # say what the stage does wrong, measured
            description = noise_stage_text(stage.name, context.search.held.real, context.stats)
        else:
            description = f"{stage.name} stage is one the camera lacks"
        return context.current.with_chain(chain), None, description

    return make


def _refitter(index: int) -> Callable[[_Context], tuple[CameraProfile, Effect, str]]:
    """A stage refitted: a fresh fit with the stage left out, or the stage (and its simpler versions) rescaled,
    whichever matches the calibration pairs better."""

    def make(context: _Context) -> tuple[CameraProfile, Effect, str]:
        stage = context.current.effects[index]
        rest = context.current.with_chain([e for i, e in enumerate(context.current.effects) if i != index])
        if type(stage).draws_only_noise():
            options = [context.search.fit_in_chain(rest, type(stage))]
        else:
            options = [context.refined(fit_candidate(stage.name, context.sources(rest), context.search.reals), rest)[0]]
        options += [context.refined(version, rest, explore=True)[0] for version in [stage, *stage.simplified()]]
        fitted = min(options, key=lambda option: context.check_gap(add_effect(rest, option)))
        return add_effect(rest, fitted), fitted, _strength_text(stage, fitted, context)

    return make


def _network_refit(context: _Context) -> tuple[CameraProfile, None, str]:
    network = finetune_network(context.current, context.search.cleans, context.search.reals)
    tuned = context.current.with_chain(list(context.current.effects))
    tuned.network = network
    return tuned, None, "a short fine-tune of the network's decoder on the calibration pairs"


#: Kinds in order of simplicity: a removal explains as much with less.
_SIMPLICITY = {"remove": 0, "add": 1, "refit": 2, "network": 3}


def _prefer_simpler(ranked: list[Change]) -> list[Change]:
    """``ranked`` (by held-out gap) with a simpler change of the same stage moved ahead of the best when it does as
    well (within half the best's reduction SE, or 2 % of its gap): removing vignetting, rather than refitting it to
    nothing."""
    if len(ranked) < 2 or ranked[0].error is not None:
        return ranked
    best = ranked[0]
    tolerance = max(0.02 * best.gap_after, 0.5 * best.reduction_se if math.isfinite(best.reduction_se) else 0.0)
    rivals = [
        change
        for change in ranked[1:]
        if change.name == best.name
        and _SIMPLICITY[change.kind] < _SIMPLICITY[best.kind]
        and change.gap_after <= best.gap_after + tolerance
    ]
    if not rivals:
        return ranked
    simpler = min(rivals, key=lambda change: _SIMPLICITY[change.kind])
    return [simpler, *[change for change in ranked if change is not simpler]]


def _strength_text(old: Effect, new: Effect, context: _Context) -> str:
    """What was wrong with a refitted stage, in words: for noise, measured on the held-out flat pixels ("noise
    stage is 2.0× the camera's noise and banded"); otherwise from the stage's magnitude."""
    if NoiseLevel.describes(type(old)):
        return noise_stage_text(old.name, context.search.held.real, context.stats)
    before, after = old.magnitude(), new.magnitude()
    if after < 0.1 * before:
        return f"{old.name} stage is one the camera shows almost none of ({after / max(before, 1e-12):.0%} of it)"
    if abs(before - after) <= 0.05 * max(before, after):
        return f"{old.name} stage has the right strength but the wrong shape"
    ratio = before / after if before > after else after / max(before, 1e-12)
    return f"{old.name} stage is {ratio:.1f}× too {'strong' if before > after else 'weak'}"


def _measured(
    search: Search,
    base: StatisticSet,
    before_gap: float,
    kind: Kind,
    name: str,
    profile: CameraProfile,
    effect: Effect | None,
    before: list[Change],
) -> Change:
    held = search.held
    stats, _ = held.statistics(profile)
    after = held.gap(stats)
    reduction = before_gap - after
    se, significant = float("nan"), False
    if reduction > search.baseline.threshold:  # otherwise it cannot be significant: skip the bootstrap
        spreads = gap_spread(held.real, [base, stats], held.indices, held.scale)
        se = float((spreads[:, 0] - spreads[:, 1]).std())
        significant = reduction > max(SIGNIFICANCE * se, search.baseline.threshold)
    families = family_gaps(held.real, stats, scale=held.scale)
    return Change(
        kind, name, profile, effect, after, reduction, se, significant, families, before=list(before), stats=stats
    )


def check_kinds(kinds: Iterable[str]) -> list[str]:
    kinds = [kinds] if isinstance(kinds, str) else list(kinds)
    unknown = [kind for kind in kinds if kind not in KINDS]
    if unknown or not kinds:
        raise ValueError(f"kinds must be one or more of {list(KINDS)}, got {kinds}")
    return kinds


def check_candidates(candidates: Iterable[str] | str | None) -> list[str]:
    return list(EFFECTS) if candidates is None else check_effect_names(candidates, "candidates")


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
    best = singles[0]
    while True:
        accepted.append(best)
        pool.discard(best.key)
        if len(accepted) >= max_changes or not pool:
            return accepted, combinations
        current: CameraProfile = best.profile  # type: ignore[assignment]  # significant ones were fitted
        stats = best.stats if best.stats is not None else search.held.statistics(current)[0]
        say(f"on top of {' + '.join(change.label for change in accepted)}:")
        extended = search.changes(current, stats, best.gap_after, list(accepted), pool, adds, say)
        combinations.extend(extended)
        if not extended or not extended[0].significant:
            return accepted, combinations
        best = extended[0]


def attribute(
    profile: CameraProfile,
    calibration: ImagePairs,
    held_out: ImagePairs,
    *,
    candidates: Iterable[str] | None = None,
    kinds: Iterable[str] = KINDS,
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
    chosen = accepted[-1] if accepted else None
    final_profile = chosen.profile if chosen is not None and chosen.profile is not None else profile
    if chosen is not None and chosen.stats is not None:  # measured with the same draws when it was evaluated
        final_stats, final_sims = chosen.stats, simulate(final_profile, held.cleans, seed, stream=held.stream)
    else:
        final_stats, final_sims = baseline.stats, baseline.sims
    final_null, _ = held.statistics(final_profile, null=True)
    return Attribution(
        baseline=baseline,
        held=held,
        singles=singles,
        combinations=combinations,
        accepted=accepted,
        final_profile=final_profile,
        final_stats=final_stats,
        final_sims=final_sims,
        noise_floor=held.gap_between(final_null, final_stats),
    )
