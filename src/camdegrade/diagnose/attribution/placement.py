"""Where in a profile's chain a candidate effect can sit, beside its physical stage's place.

A camera's chain is not always the textbook order: noise can enter after the ISP's resize or demosaic (an analog
link, a second gain stage), a codec can run at the sensor's resolution before an upscale. Where the candidate is
put matters when a stage between two places mixes neighbouring pixels (a resampler, a filter, a codec: a stage whose
signature is in a :attr:`~camdegrade.measures.Family.mixing` family, the transfer function) and the candidate's own
signature is a pattern at the pixel scale (:attr:`~camdegrade.measures.Family.pixel_pattern`: the noise's
correlation with the next pixel, the 8×8 block edges): through such a stage white noise comes out correlated and
upsampled, block edges smoothed. Between two places with no mixing stage in between, the candidate looks the same;
so the chain is cut at its mixing stages into segments and the candidate is tried once in each segment, at the
place nearest its own (:func:`placements`). Light reaches the sensor through the optics: a stage of the sensor or
later is never put before an optics stage.

Placed elsewhere than at its stage, the candidate is added beside the profile's stages of its kind (a second noise
source after the resize, the sensor's noise kept), never in place of them: the camera has both.

The places are the camera's, found on the profile as diagnosed: when an accepted change removes the stage a place
follows (a sharpening the camera lacks), the place stays, after the stage before it (:func:`placements` with
``diagnosed``), so a missing effect there is still tried once the misfit is fixed.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from camdegrade.diagnose.attribution.strength import refine_strength
from camdegrade.effects import EFFECTS, STAGES, Effect
from camdegrade.fitting.in_chain import fit_stage_in_chain
from camdegrade.measures import FAMILIES
from camdegrade.profile import CameraProfile

if TYPE_CHECKING:
    from camdegrade.diagnose.attribution.round_view import Made, Round

__all__ = [
    "Placement",
    "make_placed",
    "mixes_pixels",
    "placed_name",
    "placements",
]


@dataclass(frozen=True)
class Placement:
    """The candidate ``name`` inserted at ``index`` of a profile's chain (``after``: the mixing stage it follows, or
    ``before``: the one it precedes)."""

    name: str
    index: int
    after: str | None = None
    before: str | None = None
    #: The stage of the profile as diagnosed that this place followed, where a change has removed it since.
    was_after: str | None = None

    def insert(self, profile: CameraProfile, effect: Effect) -> CameraProfile:
        """``profile`` with ``effect`` at this place, the profile's own stages kept."""
        chain = list(profile.effects)
        chain.insert(min(self.index, len(chain)), effect)
        return profile.with_chain(chain)

    @property
    def where(self) -> str:
        """The place in words: "after resolution", "before sharpen", "at the end, where frequency_response was"."""
        if self.was_after is not None:
            return f"{f'after {self.after}' if self.after else 'at the start'}, where {self.was_after} was"
        return f"after {self.after}" if self.after is not None else f"before {self.before}"


def mixes_pixels(effect: Effect | type[Effect]) -> bool:
    """Whether a stage of this kind mixes neighbouring pixels (it changes the transfer function)."""
    return any(family in FAMILIES and FAMILIES[family].mixing for family in effect.explains)


def _moves_with_place(kind: type[Effect]) -> bool:
    return any(family in FAMILIES and FAMILIES[family].pixel_pattern for family in kind.explains)


def _own_place(chain: Sequence[Effect], kind: type[Effect]) -> int:
    """Where :meth:`CameraProfile.with_effects` puts ``kind`` in ``chain``: after every stage of its physical stage or
    an earlier one."""
    rank = STAGES.index(kind.stage)
    return sum(1 for effect in chain if STAGES.index(effect.stage) <= rank)


def _segment(chain: Sequence[Effect], index: int) -> int:
    """Which segment of ``chain`` (cut at its mixing stages) the insertion point ``index`` lies in."""
    return sum(1 for effect in chain[:index] if mixes_pixels(effect))


def placements(profile: CameraProfile, name: str, diagnosed: CameraProfile | None = None) -> list[Placement]:
    """The places other than its own where the candidate ``name`` looks different in ``profile`` (see the module):
    one per segment of the chain that neither its own place nor a stage of its kind already occupies, at the
    segment's edge nearest its own place; with ``diagnosed`` (the profile ``profile`` was changed from), also the
    places found there whose stage a change has removed. None for an effect whose signature does not depend on its
    place."""
    kind = EFFECTS[name]
    if not _moves_with_place(kind):
        return []
    out = _segment_places(list(profile.effects), name)
    if diagnosed is None or diagnosed is profile:
        return out
    chain = list(profile.effects)
    present = any(type(effect) is kind for effect in chain)
    own = _segment(chain, _own_place(chain, kind))
    for place in _segment_places(list(diagnosed.effects), name):
        moved = _moved(place, list(diagnosed.effects), chain)
        duplicate = any(moved.index == other.index for other in out) or (
            not present and _segment(chain, moved.index) == own
        )
        if moved.was_after is not None and not duplicate:
            out.append(moved)
    return out


def _segment_places(chain: list[Effect], name: str) -> list[Placement]:
    kind = EFFECTS[name]
    replaced = [effect for effect in chain if not (type(effect) is kind and kind.draws_only_noise())]
    own = _segment(replaced, _own_place(replaced, kind))
    taken = {own} | {_segment(chain, i) for i, effect in enumerate(chain) if type(effect) is kind}
    cuts = [i for i, effect in enumerate(chain) if mixes_pixels(effect)]
    optics = [i + 1 for i, effect in enumerate(chain) if effect.stage == "optics"]
    earliest = max(optics) if kind.stage != "optics" and optics else 0
    out = []
    for segment in range(len(cuts) + 1):
        if segment in taken:
            continue
        if segment > own:  # later than its own place: right after the mixing stage that opens the segment
            cut = cuts[segment - 1]
            place = Placement(name, cut + 1, after=chain[cut].name)
        else:  # earlier: right before the mixing stage that closes the segment
            cut = cuts[segment]
            place = Placement(name, cut, before=chain[cut].name)
        if place.index >= earliest:
            out.append(place)
    return out


def _moved(place: Placement, diagnosed: list[Effect], chain: list[Effect]) -> Placement:
    """``place`` (in the ``diagnosed`` chain) in ``chain``: after the last stage of ``chain`` that stood before it
    there (matched by name, in order); ``was_after`` set where the stage it followed is gone."""
    before = Counter(effect.name for effect in diagnosed[: place.index])
    last = -1
    for index, effect in enumerate(chain):
        if before[effect.name] > 0:
            before[effect.name] -= 1
            last = index
    index = last + 1
    after = chain[last].name if last >= 0 else None
    gone = place.after is not None and all(effect.name != place.after for effect in chain)
    if not gone:
        return Placement(place.name, index, after=place.after, before=place.before)
    return Placement(place.name, index, after=after, was_after=place.after)


def placed_name(placement: Placement) -> str:
    """How a placed candidate is described: "adds noise after resolution"."""
    return f"adds {placement.name} {placement.where}"


def make_placed(round_: Round, placement: Placement) -> Made:
    """The candidate fitted at ``placement`` on the round's calibration pairs: a stage that draws only noise is
    calibrated by simulating the profile with it there, against the profile's own simulation (its noise kept, so
    the fit is the noise the camera adds on top); any other is fitted against the profile's deterministic output
    and its strength refined at that place."""
    kind, current, search = EFFECTS[placement.name], round_.current, round_.search
    if kind.draws_only_noise():
        keeps_own = any(type(effect) is kind for effect in current.effects)
        sources = current.simulate(search.cleans, search.seed, stream="noise-sources", deterministic=not keeps_own)
        effect = fit_stage_in_chain(
            current,
            kind,
            search.cleans,
            search.reals,
            seed=search.seed,
            calibration_pairs=search.noise_pairs,
            sources=sources,
            insert=placement.insert,
        )
    else:
        fitted = kind.fit_within_budget(round_.sources(), search.reals)
        effect, _, _ = refine_strength(
            fitted,
            lambda candidate: round_.check_gap(placement.insert(current, candidate)),
            round_.check_gap(),
            round_.say,
        )
    return placement.insert(current, effect), effect, placed_name(placement)
