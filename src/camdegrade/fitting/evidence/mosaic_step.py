"""The colour filter array judged again once the later stages stand: a stage the effects step proposed and dropped is
put back after the noise of the finished profile and judged there by the same trace, over the same noise draws.

Why a second judgement: the effects step judges the stage in a profile of network, noise and codec; the stages fitted
after it change the very trace it is judged by. Behind a JPEG with 4:2:0 chroma the mosaic shows only in luma, and a
sharpen fitted by the texture step raises the phase contrast the codec dilutes: on bayer-jpeg's validation pairs the
stage closed 14-48 % of the luma trace's gap in the effects step's profile and 49-63 % in the finished one (four noise
draws; docs/results.md, *bayer-jpeg: why its held-out critic reads 0.71*). The stage is judged first where the stages
after it can be fitted through it (the phone's is kept there), and once more where they all stand; the bar is the
same (:data:`~camdegrade.fitting.evidence.cfa.MIN_CLOSED`). Kept there, the stages the texture, denoise and
response steps kept are fitted again through it (their steps rerun, their records replaced): a stage fitted to the
captures' spectrum without the demosaic's softening would leave the simulation's top bands short by up to 1 log2
(bayer-jpeg's validation pairs).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from camdegrade.effects import Blur, ColorFilterArray, Denoise, FrequencyResponse, Sharpen
from camdegrade.fitting.evidence.cfa import judge_cfa, noise_before_mosaic
from camdegrade.fitting.steps.base import FitStep, PairedFit, keep_and_refit_noise
from camdegrade.fitting.steps.denoise import DenoiseMatch
from camdegrade.fitting.steps.response import ResponseMatch
from camdegrade.fitting.steps.texture import TextureMatch

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
        note = {"pattern": stage.pattern, "route": route, "after": [effect.name for effect in fit.profile.effects]}
        judged = judge_cfa(fit, stage, route)
        record = keep_and_refit_noise(
            fit, f"{ColorFilterArray.name} (judged again)", judged, note, noise_before_mosaic, "refitted before"
        )
        if judged[0] is not None:
            record["refitted"] = refit_later_stages(fit)
        return record


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
