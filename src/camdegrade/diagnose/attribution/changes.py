"""The kinds of change the diagnosis tries on a profile, one class each: **add** a registered effect the profile
lacks, **remove** a stage, **refit** a stage, refit the **network**. Each kind says which changes of it are worth
trying on a profile (:meth:`ChangeKind.plans`) and how one is made (:meth:`ChangeKind.make`); :class:`Change` is one
made and measured."""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

from camdegrade.diagnose.attribution.placement import Placement, make_placed, placements
from camdegrade.diagnose.attribution.round_view import Made, Round
from camdegrade.effects import EFFECTS, Effect
from camdegrade.fitting.in_chain import replace_stage
from camdegrade.fitting.network.finetune import finetune_network
from camdegrade.measures import FAMILIES, StatisticSet
from camdegrade.measures.families.noise import NoiseLevel, noise_stage_text
from camdegrade.profile import CameraProfile

__all__ = [
    "KINDS",
    "AddEffect",
    "Change",
    "ChangeKind",
    "Plan",
    "RefitNetwork",
    "RefitStage",
    "RemoveStage",
    "add_effect",
    "check_kinds",
    "effect_params",
    "without_stage",
]


@dataclass
class Change:
    """One change to the profile (after the changes accepted before it), evaluated on the held-out pairs."""

    kind: str
    name: str
    profile: CameraProfile | None
    effect: Effect | None
    gap_after: float
    reduction: float = 0.0
    #: The bootstrap standard error of ``reduction``: NaN where it was not bootstrapped, because the reduction is
    #: below ``reduction_needed`` (it cannot count whatever its error).
    reduction_se: float = float("nan")
    significant: bool = False
    families: dict[str, float] = field(default_factory=dict)
    description: str = ""
    before: list[Change] = field(default_factory=list)
    error: str | None = None
    stats: StatisticSet | None = field(default=None, repr=False)
    #: The smallest reduction that could count where this change was tried (NaN: not evaluated).
    reduction_needed: float = float("nan")
    #: It lowers the gap significantly, but its own statistics do not agree that it is the cause
    #: (:mod:`camdegrade.diagnose.attribution.signature`): never accepted, ranked after the changes that name a cause.
    not_a_cause: bool = False

    @property
    def label(self) -> str:
        return f"{self.kind} {self.name}"

    def reduction_text(self) -> str:
        """The reduction with its standard error, or why it has none (never a NaN)."""
        if math.isfinite(self.reduction_se):
            return f"{self.reduction:+.2f} ± {self.reduction_se:.2f}"
        if math.isfinite(self.reduction_needed):
            return f"{self.reduction:+.2f}; not bootstrapped: below the {self.reduction_needed:.2f} that can count"
        return f"{self.reduction:+.2f}"

    @property
    def key(self) -> tuple[str, str]:
        return self.kind, self.name

    @property
    def chain(self) -> list[Change]:
        """This change after the ones accepted before it."""
        return [*self.before, self]


@dataclass(frozen=True)
class Plan:
    """One change worth trying: its kind, its name, what it changes (an effect name or a stage's index), and its
    place in the order changes are tried (candidates, then stage by stage, then the network)."""

    kind: ChangeKind
    name: str
    target: Any
    order: tuple[int, ...]


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


def without_stage(profile: CameraProfile, index: int) -> CameraProfile:
    return profile.with_chain([e for i, e in enumerate(profile.effects) if i != index])


class ChangeKind:
    """One kind of change: which changes of it to try on a profile, and how one is made."""

    kind: ClassVar[str] = ""
    #: Kinds in order of simplicity (lower is simpler): a removal explains as much with less.
    simplicity: ClassVar[int] = 0

    def plans(self, current: CameraProfile, adds: Sequence[str], axes: set[str]) -> list[Plan]:
        """The changes of this kind worth trying on ``current``, given the effects that may be added and the
        significant signature families ``axes``."""
        raise NotImplementedError

    def make(self, round_: Round, target: Any) -> Made:
        """``(profile, fitted effect or None, description)``, fitted on the round's calibration pairs."""
        raise NotImplementedError


class AddEffect(ChangeKind):
    """Add a registered effect the profile lacks: fitted against the profile's deterministic output, its strength
    refined for its place in the chain (noise: calibrated by simulating the whole chain)."""

    kind = "add"
    simplicity = 1

    def plans(self, current: CameraProfile, adds: Sequence[str], axes: set[str]) -> list[Plan]:
        """Each candidate the profile lacks at its stage, and each at the other places in the chain where it would
        look different (:func:`~camdegrade.diagnose.attribution.placement.placements`; those of the profile as diagnosed
        are added by :meth:`~camdegrade.diagnose.attribution.search.Search.plans`)."""
        return self.placed_plans(current, adds)

    def placed_plans(
        self, current: CameraProfile, adds: Sequence[str], diagnosed: CameraProfile | None = None
    ) -> list[Plan]:
        present = {type(effect) for effect in current.effects}
        own = [Plan(self, name, name, (0, i)) for i, name in enumerate(adds) if EFFECTS[name] not in present]
        placed = [
            Plan(self, name, place, (0, i, j + 1))
            for i, name in enumerate(adds)
            for j, place in enumerate(placements(current, name, diagnosed))
        ]
        return own + placed

    def make(self, round_: Round, target: Any) -> Made:
        if isinstance(target, Placement):
            return make_placed(round_, target)
        cls = EFFECTS[target]
        if cls.draws_only_noise() or cls.calibrates_in_chain():
            effect = round_.search.fit_in_chain(round_.current, cls)
        else:
            fitted = cls.fit_within_budget(round_.sources(), round_.search.reals)
            effect, _ = round_.refined(fitted, round_.current)
        return add_effect(round_.current, effect), effect, f"adds {target}"


def _stage_plans(kind: ChangeKind, current: CameraProfile, axes: set[str]) -> list[Plan]:
    """A plan for every stage whose signature the gap shows: a stage can be wrong only there."""
    return [
        Plan(kind, stage.name, index, (1, index))
        for index, stage in enumerate(current.effects)
        if set(stage.explains) & axes
    ]


class RemoveStage(ChangeKind):
    """Leave a stage out (the camera may not have it)."""

    kind = "remove"
    simplicity = 0

    def plans(self, current: CameraProfile, adds: Sequence[str], axes: set[str]) -> list[Plan]:
        return _stage_plans(self, current, axes)

    def make(self, round_: Round, target: Any) -> Made:
        stage = round_.current.effects[target]
        if NoiseLevel.describes(type(stage)):  # say what the stage does wrong, measured
            description = noise_stage_text(stage.name, round_.search.held.real, round_.stats)
        else:
            description = f"{stage.name} stage is one the camera lacks"
        return without_stage(round_.current, target), None, description


class RefitStage(ChangeKind):
    """Refit a stage (too strong, too weak, the wrong shape): fitted anew with the stage left out, or the stage (and
    its simpler versions) rescaled, whichever matches the calibration pairs better."""

    kind = "refit"
    simplicity = 2

    def plans(self, current: CameraProfile, adds: Sequence[str], axes: set[str]) -> list[Plan]:
        """A plan for every stage the gap shows that can be fitted anew (a learned stage has no pair fitter)."""
        plans = _stage_plans(self, current, axes)
        return [plan for plan in plans if type(current.effects[plan.target]).has_pair_fitter()]

    def make(self, round_: Round, target: Any) -> Made:
        stage = round_.current.effects[target]
        rest = without_stage(round_.current, target)
        if type(stage).draws_only_noise() or type(stage).calibrates_in_chain():
            options = [round_.search.fit_in_chain(rest, type(stage))]
        else:
            fresh = EFFECTS[stage.name].fit_within_budget(round_.sources(rest), round_.search.reals)
            options = [round_.refined(fresh, rest)[0]]
        options += [round_.refined(version, rest, explore=True)[0] for version in [stage, *stage.simplified()]]
        fitted = min(options, key=lambda option: round_.check_gap(add_effect(rest, option)))
        return add_effect(rest, fitted), fitted, _refit_text(stage, fitted, round_)


def _refit_text(old: Effect, new: Effect, round_: Round) -> str:
    """What was wrong with a refitted stage, in words: for noise, measured on the held-out flat pixels ("noise
    stage is 2.0× the camera's noise and banded"); otherwise from the stage's magnitude."""
    if NoiseLevel.describes(type(old)):
        return noise_stage_text(old.name, round_.search.held.real, round_.stats)
    before, after = old.magnitude(), new.magnitude()
    if after < 0.1 * before:
        return f"{old.name} stage is one the camera shows almost none of ({after / max(before, 1e-12):.0%} of it)"
    if abs(before - after) <= 0.05 * max(before, after):
        return f"{old.name} stage has the right strength but the wrong shape"
    ratio = before / after if before > after else after / max(before, 1e-12)
    return f"{old.name} stage is {ratio:.1f}× too {'strong' if before > after else 'weak'}"


class RefitNetwork(ChangeKind):
    """A short fine-tune of the network through the stages after it, when a family the network's own artefacts
    show (:attr:`~camdegrade.measures.Family.network_fault`: 8×8 blocks, the high-frequency transfer) is significant.
    Effects explain those families too (JPEG blocks, blur), so their candidates are tried beside it."""

    kind = "network"
    simplicity = 3

    def plans(self, current: CameraProfile, adds: Sequence[str], axes: set[str]) -> list[Plan]:
        if current.network is None or not any(FAMILIES[axis].network_fault for axis in axes):
            return []
        return [Plan(self, "network", None, (2,))]

    def make(self, round_: Round, target: Any) -> Made:
        network = finetune_network(round_.current, round_.search.cleans, round_.search.reals)
        tuned = round_.current.with_chain(list(round_.current.effects))
        tuned.network = network
        return tuned, None, "a short fine-tune of the network's decoder on the calibration pairs"


#: kind → how it is made, in the order the kinds are named to users.
KINDS: dict[str, ChangeKind] = {kind.kind: kind for kind in (AddEffect(), RemoveStage(), RefitStage(), RefitNetwork())}


def check_kinds(kinds: Iterable[str]) -> list[str]:
    kinds = [kinds] if isinstance(kinds, str) else list(kinds)
    unknown = [kind for kind in kinds if kind not in KINDS]
    if unknown or not kinds:
        raise ValueError(f"kinds must be one or more of {list(KINDS)}, got {kinds}")
    return kinds
