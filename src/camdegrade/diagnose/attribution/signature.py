"""Whether a change's own statistics agree that it is the cause, not only that it lowers the gap.

The gap sums every family, so a change can close it through families its effect does not explain: a network
fine-tune absorbs a colour cast, a smoothing refit hides noise it does not draw, a tone curve evens out a misfit of
the profile's other stages. A change names a cause only where the statistics its effect's signature names
(:attr:`~camdegrade.effects.Effect.explains`, and for a pixel-scale pattern such as noise also what the later
stages that mix pixels make of it, :func:`own_families`; for the network, the families of its own faults,
:attr:`~camdegrade.measures.Family.network_fault`) say so: at least one of them differs between the simulation and
the captures beyond the measurement's own noise (the ``where`` rule: above three times its null band and above one
unit), and the change moves them toward the captures by as much as any reduction must be to count (the rule the
whole gap's reduction is held to, :mod:`camdegrade.diagnose.attribution.search`: above three bootstrap standard errors
over the held-out pairs and above the smallest reduction that can count on that gap). What it takes off the other
families is a side effect, not evidence: an effect moves more than its signature (a vignetting's dark corners lower the
tone residual of every bin too), so the other families neither count for nor against it.

A change whose signature is the transfer function (a :attr:`~camdegrade.measures.Family.mixing` family: a blur, a
sharpening, a denoiser, a codec, the network) also changes what a person sees, the texture's band power: where it
takes the texture away from the camera's (its largest visible band difference grows by more than a band must differ
to be seen, :data:`~camdegrade.measures.visible.TEXTURE_LOG2`), the transfer it fixes is not the camera's detail but
something else in the captures (noise, aliasing the profile lacks), and it is not the cause: a frequency response
removed from a phone's profile matches the transfer of the captures and leaves the texture too smooth
(docs/results.md, *Which change is the cause*).

Two statistics only one cause leaves outrank the rest. Where things are (a :attr:`~camdegrade.measures.Family.geometric`
family, the displacement registered against the clean image): a misalignment that fixes it is named even where the
simulator's interpolation takes the texture away from the camera's (a shift resampled by a smoother kernel than the
camera's; the texture is said beside it). And a change to the ISP's resampler, whose transfer every smoothing stage
shares, is a cause only where the resampling trace says the resampling differs
(:mod:`camdegrade.diagnose.attribution.resampler`).

A change that fails is kept in the ranking, marked (:attr:`Agreement.agrees` false, said in its description), and
never accepted.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch

from camdegrade.diagnose.attribution.placement import mixes_pixels
from camdegrade.diagnose.attribution.resampler import resampler_unsupported
from camdegrade.diagnose.heldout import MIN_REDUCTION, SIGNIFICANCE, HeldOut
from camdegrade.effects import EFFECTS, Effect
from camdegrade.measures import FAMILIES, StatisticSet, family_gaps
from camdegrade.measures.visible import TEXTURE_LOG2, TextureComparison, compare_texture
from camdegrade.profile import CameraProfile

if TYPE_CHECKING:
    from camdegrade.diagnose.attribution.changes import Change
    from camdegrade.diagnose.attribution.round_view import Round

__all__ = ["Agreement", "agreement", "judge_cause", "not_a_cause_clause", "own_families"]


def own_families(kind: str, name: str, later: Sequence[Effect] = ()) -> tuple[str, ...]:
    """The families whose signature the change names: its effect's (add, remove, refit) or the network's faults.
    An effect whose signature is a pattern at the pixel scale (:attr:`~camdegrade.measures.Family.pixel_pattern`:
    noise, a codec's blocks) shows it through the stages ``later`` in the chain that mix pixels as theirs too: noise
    before a codec changes its block edges, blocks before an upscale its transfer function."""
    if kind == "network":
        return tuple(family for family, cls in FAMILIES.items() if cls.network_fault)
    own = [family for family in EFFECTS[name].explains if family in FAMILIES]
    if any(FAMILIES[family].pixel_pattern for family in own):
        own += [family for stage in later if mixes_pixels(stage) for family in stage.explains if family in FAMILIES]
    return tuple(dict.fromkeys(own))


def _later(change: Change, round_: Round) -> list[Effect]:
    """The stages after the one ``change`` adds, refits or removes (the last of its kind), in the chain it acts on."""
    profile = round_.current if change.kind == "remove" else change.profile
    if change.kind == "network" or profile is None:
        return []
    chain = list(profile.effects)
    places = [index for index, stage in enumerate(chain) if stage.name == change.name]
    return chain[places[-1] + 1 :] if places else []


@dataclass
class Agreement:
    """What the change's own families say: which of them differ significantly before it (``differing``), by how
    much it lowers their summed score (``reduction`` ± ``se``), and the smallest reduction that can count where it
    was tried (``needed``)."""

    families: tuple[str, ...]
    differing: tuple[str, ...]
    reduction: float
    se: float
    needed: float
    #: The texture before and after the change, where it moves away from the camera's (else None).
    texture: tuple[TextureComparison, TextureComparison] | None = None
    #: Where the texture moves away: the agreement of the change's geometric families alone (else None).
    geometry: Agreement | None = None

    @property
    def agrees(self) -> bool:
        if self.texture is not None:  # only where things are, which a texture cannot fake, can still name it
            return self.geometry is not None and self.geometry.agrees
        if not (self.differing and math.isfinite(self.se)):
            return False
        return self.reduction > max(SIGNIFICANCE * self.se, self.needed, MIN_REDUCTION)

    def describe(self) -> str:
        """Why it is not a cause, in words (empty when it agrees)."""
        if self.agrees:
            return ""
        own = ", ".join(self.families) or "none"
        if self.texture is not None:
            return f"not a cause: it moves its own statistics ({own}) but the texture away from the camera's: " + (
                self.texture[1].describe()
            )
        if not self.differing:
            return f"not a cause: its own statistics ({own}) match the camera already"
        return (
            f"not a cause: it lowers its own statistics ({own}) by {self.reduction:+.2f} ± {self.se:.2f}, less than "
            f"a reduction must be to count ({max(SIGNIFICANCE * self.se, self.needed, MIN_REDUCTION):.2f})"
        )


def agreement(change: Change, round_: Round) -> Agreement:
    """The change's own families before it (the round's profile) and after it, on the held-out pairs."""
    held, baseline = round_.search.held, round_.search.baseline
    families = own_families(change.kind, change.name, _later(change, round_))
    before = family_gaps(held.real, round_.stats, scale=held.scale)
    nulls = baseline.null_families
    differing = tuple(f for f in families if before[f] > max(3 * nulls.get(f, 0.0), 1.0))
    after = change.families
    reduction = sum(before[f] - after[f] for f in families)
    se = _own_spread(held, round_.stats, change.stats, families) if differing and change.stats is not None else math.nan
    transfer = any(FAMILIES[f].mixing for f in own_families(change.kind, change.name))
    texture = _texture_away(change, round_) if transfer else None
    geometry = _geometry(change, round_, differing, before) if texture is not None else None
    return Agreement(families, differing, reduction, se, change.reduction_needed, texture, geometry)


def _geometry(change: Change, round_: Round, differing: tuple[str, ...], before: dict[str, float]) -> Agreement | None:
    """The agreement of the change's geometric families alone (:attr:`~camdegrade.measures.Family.geometric`), or
    None when it has none: a misalignment resampled by the simulator's interpolator moves the texture as a side
    effect of the interpolator, not of the cause, while the displacement it fixes is one no texture explains."""
    geometric = tuple(f for f in own_families(change.kind, change.name) if FAMILIES[f].geometric)
    if not geometric:
        return None
    shown = tuple(f for f in geometric if f in differing)
    moved = sum(before[f] - change.families[f] for f in geometric)
    held = round_.search.held
    spread = (
        _own_spread(held, round_.stats, change.stats, geometric) if shown and change.stats is not None else math.nan
    )
    return Agreement(geometric, shown, moved, spread, change.reduction_needed)


def _texture_away(change: Change, round_: Round) -> tuple[TextureComparison, TextureComparison] | None:
    """The texture of the round's profile and of the changed one on the held-out pairs, where the change takes it
    away from the camera's (its largest visible band difference grows by more than :data:`TEXTURE_LOG2`)."""
    held = round_.search.held
    if change.profile is None:
        return None
    before = _texture(held, round_.current)
    after = compare_texture(change.profile.simulate(held.cleans, held.seed, stream=held.stream), held.reals)
    return (before, after) if after.worst > before.worst + TEXTURE_LOG2 else None


#: The texture of the last profile a round measured changes on (its held-out simulations against the captures).
_TEXTURES: dict[tuple[int, int], tuple[HeldOut, CameraProfile, TextureComparison]] = {}


def _texture(held: HeldOut, profile: CameraProfile) -> TextureComparison:
    cached = _TEXTURES.get((id(held), id(profile)))
    if cached is None or cached[0] is not held or cached[1] is not profile:
        _TEXTURES.clear()
        sims = profile.simulate(held.cleans, held.seed, stream=held.stream)
        cached = held, profile, compare_texture(sims, held.reals)
        _TEXTURES[(id(held), id(profile))] = cached
    return cached[2]


def _own_spread(held: HeldOut, before: StatisticSet, after: StatisticSet, families: tuple[str, ...]) -> float:
    """The bootstrap standard error (over the held-out pairs) of the own families' reduction."""
    first = _resampled(held, before)
    second = [family_gaps(held.real, after, index, held.scale) for index in held.indices]
    return float(torch.tensor([sum(a[f] - b[f] for f in families) for a, b in zip(first, second)]).std())


#: The family scores of the last profile a round measured changes on, on every resample (a round judges all its
#: changes against one profile).
_RESAMPLED: dict[tuple[int, int], tuple[HeldOut, StatisticSet, list[dict[str, float]]]] = {}


def _resampled(held: HeldOut, stats: StatisticSet) -> list[dict[str, float]]:
    key = (id(held), id(stats))
    cached = _RESAMPLED.get(key)
    if cached is None or cached[0] is not held or cached[1] is not stats:
        _RESAMPLED.clear()
        cached = held, stats, [family_gaps(held.real, stats, index, held.scale) for index in held.indices]
        _RESAMPLED[key] = cached
    return cached[2]


def judge_cause(change: Change, round_: Round) -> None:
    """Mark a significant ``change`` whose own statistics do not agree, or, for the resampler, whose trace does not
    (see the module), as not significant, and say why in its description; it then ranks after the changes that name
    a cause (:attr:`Change.not_a_cause`). A misalignment named by where things are says the texture it leaves."""
    if not change.significant:
        return
    verdict = agreement(change, round_)
    if verdict.agrees and verdict.texture is not None and verdict.geometry is not None:
        named = f"named by where things are ({', '.join(verdict.geometry.families)}); {verdict.texture[1].describe()}"
        change.description = "; ".join(part for part in (change.description, named) if part)
        return
    said = verdict.describe() or resampler_unsupported(change, round_)
    if not said:
        return
    change.significant, change.not_a_cause = False, True
    change.description = "; ".join(part for part in (change.description, said) if part)


def not_a_cause_clause(changes: list[Change]) -> str:
    """The changes that lower the gap significantly but are not a cause, in words (for a verdict that accepts
    nothing), or nothing."""
    named = [change for change in changes if change.not_a_cause]
    if not named:
        return ""
    said = "; ".join(f"{change.label} (gap −{change.reduction:.2f}): {change.description}" for change in named)
    return f" Lowering the gap without naming its cause: {said}."
