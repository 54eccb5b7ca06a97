"""The colour filter array judged again once the later stages stand: a stage the effects step proposed and dropped is
put back after the noise of the finished profile and judged there by the same trace, over the same noise draws.

Why a second judgement: the effects step judges the stage in a profile of network, noise and codec; the stages fitted
after it change the very trace it is judged by. Behind a JPEG with 4:2:0 chroma the mosaic shows only in luma, and a
sharpen fitted by the texture step raises the phase contrast the codec dilutes: on bayer-jpeg's validation pairs the
stage closed 14-48 % of the luma trace's gap in the effects step's profile and 49-63 % in the finished one (four noise
draws; docs/results.md, *bayer-jpeg: why its held-out critic reads 0.71*). The stage is judged first where the stages
after it can be fitted through it (the phone's is kept there), and once more where they all stand; the bar is the
same (:data:`~camdegrade.fitting.evidence.cfa.MIN_CLOSED`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from camdegrade.effects import ColorFilterArray
from camdegrade.fitting.evidence.cfa import judge_cfa, noise_before_mosaic
from camdegrade.fitting.steps.base import FitStep, PairedFit, keep_and_refit_noise

__all__ = ["MosaicRejudged", "deferred_stage"]


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
        return keep_and_refit_noise(
            fit, f"{ColorFilterArray.name} (judged again)", judged, note, noise_before_mosaic, "refitted before"
        )
