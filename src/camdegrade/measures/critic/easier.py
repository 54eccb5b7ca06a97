"""When a fresh critic says a change to a simulation made it easier to tell from the captures, and how a fit's
critic is run: the rule of the learned texture stage's gate (:mod:`camdegrade.fitting.two_sample.gate`) and of the
cfa stage's guard (:mod:`camdegrade.fitting.evidence.mosaic_guard`), and the seeds and scenes of the critic at the
end of a paired fit (:mod:`camdegrade.fitting.quality`). Here, below the fit, so that a fit step can use them."""

from __future__ import annotations

__all__ = ["CRITIC_SLACK", "FIT_CRITIC_SEEDS", "MIN_CRITIC_SCENES", "critic_not_easier"]

#: How much easier the fresh critic may find the simulation with the stage (accuracy; two critics on 8–10 held-out
#: images spread by about 0.05, docs/results.md).
CRITIC_SLACK = 0.02
#: The critic at the end of a fit trains on half the validation scenes and is scored on the other half; with fewer
#: than this many scenes one side would hold a single scene, whose bootstrap interval says nothing.
MIN_CRITIC_SCENES = 4
#: Critic seeds at the end of a fit, each training one critic per half of the validation scenes (4 critics in all):
#: single critics of the City100 built-in's image-only test range from 0.70 to 0.83 (docs/results.md). On City100's 8
#: validation frames the 8 critics of both modes take 21 s, one per mode took 4 s (AMD EPYC Zen 3, 2 threads).
FIT_CRITIC_SEEDS = 2


def critic_not_easier(without: float, with_stage: float) -> bool:
    """Whether a fresh critic's accuracy ``with_stage`` is at most :data:`CRITIC_SLACK` above ``without``'s: the
    change makes the simulation no easier to tell from the captures."""
    return with_stage - without <= CRITIC_SLACK
