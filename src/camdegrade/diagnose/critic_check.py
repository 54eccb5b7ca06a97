"""The statistics' choice checked by what a model trained on the simulation would see.

The held-out statistics accept a change when it closes their gap, and some of their families count only detail
that is coherent with the clean image. On City100 they accept refitting denoise 10× stronger, which smooths the
texture the phone's sharpening leaves, and a critic that sees the image alone then tells the simulation from the
camera more easily (0.66 [0.64–0.69] → 0.79 [0.74–0.85]). So each accepted change, in order, is simulated on the
held-out pairs and judged by a fresh image-only critic (:func:`~camdegrade.diagnose.critique.critiques`: two folds
of the held-out pairs, never a calibration pair) and by the texture a person sees (band power,
:func:`~camdegrade.measures.visible.compare_texture`). The first change after which the critic is surer than the
upper end of its interval before it, and sure at all, *and* the texture is further from the camera's (its largest
significant band difference grows by more than a band must differ to be seen, 0.25 log2) is held back, with every
change accepted after it.

The critic alone is not enough: a right change can make it surer by laying bare what is left. A camera with twice
the profile's noise and a tone curve the profile lacks: adding the tone curve closes 96 % of the statistics' gap,
and from the image alone the critic goes 0.57 → 0.78, now seeing the noise (``tests/test_diagnose_critic.py``).
The texture does not move there; on City100 the denoise refit takes it from within the camera's to too smooth.

Nor is a change held back that closes most of the gap (more than half of it above the profile against itself,
:data:`MOST`): an exposure error fixed by a tone curve leaves the noise and the texture as the only differences, and
a critic that sees them more easily has found what is left, not a fault of the fix. The change is kept, and what it
uncovers is reported (:attr:`CriticCheck.uncovered`): the critic before and after it, the family that differs most
with it, and the texture.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from camdegrade.diagnose.attribution.attribute import Attribution
from camdegrade.diagnose.attribution.changes import Change
from camdegrade.diagnose.critique import CRITIC_CHANCE, Critique, critiques
from camdegrade.measures.visible import TEXTURE_LOG2, TextureComparison, compare_texture
from camdegrade.pairs.pairset import PairSet

__all__ = ["MOST", "CriticCheck", "check_changes", "closes_most", "uncovered_clause"]

#: A change that closes more than this share of the gap (above the profile against itself) is never held back.
MOST = 0.5


@dataclass
class CriticCheck:
    """The image-only critic on the profile as given and after each accepted change it let through (``steps``:
    ``(what was changed, the critic)``), and the change it held back with the critic on it (``held_back``)."""

    steps: list[tuple[str, Critique]]
    held_back: tuple[Change, Critique] | None = None
    #: The changes the statistics accepted after the one held back (held back with it, unjudged).
    later: list[Change] = field(default_factory=list)
    #: The texture before and after the change held back.
    texture: tuple[TextureComparison, TextureComparison] | None = None
    #: The changes kept although the critic is surer with them, because they close most of the gap: each with
    #: the critic before and after it and the texture after it (what it uncovers).
    uncovered: list[tuple[Change, Critique, Critique, TextureComparison]] = field(default_factory=list)

    @property
    def kept(self) -> int:
        """How many of the accepted changes it let through."""
        return len(self.steps) - 1

    def to_dict(self) -> dict:
        """For the report: each change let through and the one held back, with the critic's accuracy after it."""
        held_back = None
        if self.held_back is not None:
            change, critique = self.held_back
            held_back = {"change": change.label, **_score(critique)}
            if self.texture is not None:
                held_back["texture_before"], held_back["texture_after"] = (t.describe() for t in self.texture)
        steps = [{"change": label, **_score(critique)} for label, critique in self.steps]
        uncovered = [
            {"change": change.label, "before": _score(before), "after": _score(after), "texture": texture.describe()}
            for change, before, after, texture in self.uncovered
        ]
        return {
            "steps": steps,
            "held_back": held_back,
            "later_held_back": [change.label for change in self.later],
            "uncovered": uncovered,
        }


def check_changes(
    result: Attribution, held: PairSet, held_pairs: list, seed: int, say: Callable[[str], None]
) -> CriticCheck:
    """Judge ``result``'s accepted changes in order by a fresh image-only critic (see the module); ``held`` and
    ``held_pairs`` are the held-out pairs ``result`` was measured on."""

    def critic(label: str, sims: list) -> Critique:
        (out,) = critiques([(label, sims)], held_pairs, held.names, held.scenes, seed, say, image_only=True).values()
        return out

    reals = result.held.reals
    check = CriticCheck([("the profile as given", critic("before (image only)", result.baseline.sims))])
    texture = compare_texture(result.baseline.sims, reals)
    for index, change in enumerate(result.accepted):
        if change.profile is None:
            raise ValueError(f"accepted change {change.label!r} has no profile to simulate")
        sims = change.profile.simulate(result.held.cleans, result.held.seed, stream=result.held.stream)
        after = critic(f"with {' + '.join(c.label for c in change.chain)} (image only)", sims)
        previous = check.steps[-1][1].result
        surer = after.result.accuracy > previous.high and after.result.low > CRITIC_CHANCE
        texture_after = compare_texture(sims, reals)
        if surer and closes_most(change, result.baseline.null):
            check.uncovered.append((change, check.steps[-1][1], after, texture_after))
        elif surer and texture_after.worst > texture.worst + TEXTURE_LOG2:
            check.held_back, check.later = (change, after), result.accepted[index + 1 :]
            check.texture = (texture, texture_after)
            return check
        check.steps.append((change.label, after))
        texture = texture_after
    return check


def closes_most(change: Change, null: float) -> bool:
    """Whether ``change`` takes more than :data:`MOST` of the gap it was tried on, above the noise ``null`` (the
    profile against itself)."""
    gap_now = change.gap_after + change.reduction
    return change.reduction > MOST * max(0.0, gap_now - null)


def uncovered_clause(check: CriticCheck | None) -> str:
    """What the kept changes that made the critic surer uncover, in words, or nothing."""
    if check is None:
        return ""
    parts = []
    for change, before, after, texture in check.uncovered:
        b, a = before.result, after.result
        family = max(change.families, key=change.families.__getitem__) if change.families else None
        left = f"; what is left differs most in {family} ({change.families[family]:.2f})" if family else ""
        parts.append(
            f" Uncovered: with {change.label}, which closes most of the gap, a critic tells the simulation from the "
            f"camera more easily from the image alone ({b.accuracy:.2f} [{b.low:.2f}–{b.high:.2f}] → "
            f"{a.accuracy:.2f} [{a.low:.2f}–{a.high:.2f}]): it sees what the change leaves{left}; {texture.describe()}."
        )
    return "".join(parts)


def _score(critique: Critique) -> dict:
    result = critique.result
    return {"accuracy": round(result.accuracy, 4), "low": round(result.low, 4), "high": round(result.high, 4)}
