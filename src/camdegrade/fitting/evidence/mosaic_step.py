"""The colour filter array judged again once the later stages stand: a stage the effects step proposed and dropped is
put back after the noise of the finished profile, the noise refitted before it as the effects step does and the
stages of the texture, denoise and response steps fitted again through it (their steps rerun); that profile is judged
against the finished one by the same distance to the captures' trace (the luma route: its whole form), over the same
noise draws, and replaces it where it closes at least :data:`~camdegrade.fitting.evidence.cfa.MIN_CLOSED` of it and
a fresh image-only critic on the validation pairs finds it no easier to tell from the captures
(:func:`~camdegrade.fitting.evidence.mosaic_guard.critic_guard`).

Why a second judgement: the effects step judges the stage in a profile of network, noise and codec; the stages fitted
after it change the very trace it is judged by. Behind a JPEG with 4:2:0 chroma the mosaic shows only in luma, and a
sharpen fitted by the texture step raises the phase contrast the codec dilutes: on bayer-jpeg's validation pairs the
stage closed 14-48 % of the luma trace's gap in the effects step's profile and 49-63 % in the finished one (four noise
draws; docs/results.md, *bayer-jpeg: why its held-out critic reads 0.71*). Why the later stages are fitted through it
before it is judged: a sharpen fitted to the captures' spectrum without the demosaic's softening leaves the
simulation's top bands short by up to 1 log2, and the one fitted through it sharpens the phase pattern as the
camera's chain does (docs/results.md, *The cfa stage proposed by the mosaic's form*).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

from camdegrade.effects import Blur, ColorFilterArray, Denoise, FrequencyResponse, Sharpen
from camdegrade.fitting.evidence.cfa import JUDGE_DRAWS, MIN_CLOSED, READS, TOLERANCES, distance_to, noise_before_mosaic
from camdegrade.fitting.evidence.mosaic_guard import critic_guard, guard_line
from camdegrade.fitting.evidence.statistic import simulated_draws
from camdegrade.fitting.steps.base import FitStep, PairedFit, closes_gap
from camdegrade.fitting.steps.denoise import DenoiseMatch
from camdegrade.fitting.steps.response import ResponseMatch
from camdegrade.fitting.steps.texture import TextureMatch
from camdegrade.profile import CameraProfile

#: The steps fitted after the effects step to the captures' spectrum and detail, and the stages they add.
LATER_STEPS: tuple[type[FitStep], ...] = (TextureMatch, DenoiseMatch, ResponseMatch)
LATER_STAGES: tuple[type, ...] = (Blur, Sharpen, Denoise, FrequencyResponse)

__all__ = ["LATER_STAGES", "LATER_STEPS", "MosaicRejudged", "deferred_stage", "refit_later_stages"]


def deferred_stage(fit: PairedFit) -> tuple[ColorFilterArray, str] | None:
    """The stage (and its route) the effects step proposed and dropped, from its ``cfa`` record; ``None`` where it
    proposed none, kept it, or did not run."""
    note = fit.records.get("effects", {}).get(ColorFilterArray.name)
    if not note or note.get("kept") or "amount" not in note:
        return None
    return ColorFilterArray(note["pattern"], note["amount"], note["demosaic"]), note["route"]


@dataclass(frozen=True)
class MosaicRejudged(FitStep):
    """The recipe's ``mosaic`` step, after the texture and response steps: the dropped cfa stage judged again in the
    finished profile (:func:`~camdegrade.fitting.evidence.cfa.judge_cfa`); kept, the noise is refitted before it as
    the effects step does. Records nothing where the effects step left no stage to judge again."""

    name: ClassVar[str] = "mosaic"

    def propose(self, fit: PairedFit) -> tuple[ColorFilterArray, str] | None:
        return deferred_stage(fit)

    def run(self, fit: PairedFit) -> dict[str, Any] | None:
        proposal = self.propose(fit)
        return None if proposal is None else self.judge(fit, proposal)

    def judge(self, fit: PairedFit, proposal: tuple[ColorFilterArray, str]) -> dict[str, Any]:
        stage, route = proposal
        finished, records = fit.profile, {name: fit.records.get(name) for name in _later_names()}
        fit.profile = fit.profile.with_effects(stage)
        noise_line = noise_before_mosaic(fit)
        refitted = refit_later_stages(fit)
        distance = _distance_of(fit, stage, route)
        without, within = distance(finished), distance(fit.profile)
        closes = closes_gap(0.0, without, within, TOLERANCES[route], MIN_CLOSED)
        guard = critic_guard(fit, finished, fit.profile) if closes else None
        kept = closes and guard is not None and guard["not_easier"]
        line = (
            f"effect cfa (judged again, {', '.join(refitted) or 'no later step'} refitted through it): "
            f"{stage.pattern} {stage.demosaic} at {float(stage.amount):.3f}: {READS[route]} distance to the "
            f"captures' {without:.3f} in the finished profile, {within:.3f} with the stage"
            f"{'; ' + guard_line(guard) if guard else ''} -> {'kept' if kept else 'dropped'}"
        )
        fit.say(line)
        if not kept:
            fit.profile = finished
            fit.records.update({name: record for name, record in records.items() if record is not None})
        elif noise_line is not None:
            fit.say(noise_line)
        record = {"kept": kept, "pattern": stage.pattern, "route": route, "demosaic": stage.demosaic}
        record |= {"amount": round(float(stage.amount), 3), "distance_without": round(without, 4)}
        record |= {"distance_with": round(within, 4), "refitted": refitted, "evidence": fit.evidence_pairs[1]}
        record |= {"closes": closes, "critic": guard}
        return record | ({"noise": noise_line} if kept and noise_line else {})


def _later_names() -> list[str]:
    return [step.name for step in LATER_STEPS]


def _distance_of(fit: PairedFit, stage: ColorFilterArray, route: str) -> Callable[[CameraProfile], float]:
    """A profile's distance to the judged captures' trace (:func:`~camdegrade.fitting.evidence.cfa.distance_to`, the
    captures read once), its simulation drawn :data:`~camdegrade.fitting.evidence.cfa.JUDGE_DRAWS` times."""
    pairs, _ = fit.evidence_pairs
    cleans, captures = (list(side) for side in zip(*pairs, strict=True))
    to_captures = distance_to(captures, stage.pattern, route)
    return lambda profile: to_captures(
        simulated_draws(profile, cleans, JUDGE_DRAWS, stream="cfa-evidence", eight_bit=fit.eight_bit)
    )


def refit_later_stages(fit: PairedFit) -> list[str]:
    """The stages of :data:`LATER_STAGES` taken out of ``fit``'s profile and the steps of :data:`LATER_STEPS` that
    ran rerun on it (their records replaced); the names of the steps rerun."""
    fit.profile = fit.profile.with_chain([e for e in fit.profile.effects if not isinstance(e, LATER_STAGES)])
    rerun = []
    for step_class in LATER_STEPS:
        step = step_class()
        if step.name in fit.records and fit.unmet(step) is None:
            record = step.run(fit)
            if record is not None:
                fit.records[step.name] = record
            rerun.append(step.name)
    return rerun
