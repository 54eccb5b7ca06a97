"""The critic's word on a cfa stage its form's distance would keep (the effects step's
:class:`~camdegrade.fitting.evidence.cfa.CfaStage`, and the ``mosaic`` step's judgement again): a fresh image-only
critic (:func:`~camdegrade.measures.critic.repeated_critic_test`) on the validation pairs, never pairs a stage was
fitted on, must not find the profile with the stage easier to tell from the captures than the profile without it,
by more than the learned texture gate's :data:`~camdegrade.measures.critic.easier.CRITIC_SLACK` (the gate's rule,
:func:`~camdegrade.measures.critic.easier.critic_not_easier`).

Why the form's distance is not enough: on a BGGR camera demosaiced by OpenCV's edge-aware method (behind JPEG 88) a
bilinear BGGR stage at 0.75 closed the luma form's distance from 0.140 to 0.015 while the held-out image-only critic
rose from 0.81 to 0.91: the statistic says a mosaic is there, the stage's demosaic is not the camera's
(docs/results.md, *The cfa stage proposed by the mosaic's form*). Where the critic cannot be trained (no
validation pairs, or fewer than :data:`~camdegrade.measures.critic.easier.MIN_CRITIC_SCENES` validation scenes) the
stage is not kept: the form alone is what failed there.
"""

from __future__ import annotations

from typing import Any

from camdegrade.fitting.steps.base import PairedFit
from camdegrade.measures.critic import repeated_critic_test
from camdegrade.measures.critic.easier import CRITIC_SLACK, FIT_CRITIC_SEEDS, MIN_CRITIC_SCENES, critic_not_easier
from camdegrade.profile import CameraProfile

__all__ = ["critic_guard", "guard_kept", "guard_line"]


def critic_guard(fit: PairedFit, finished: CameraProfile, with_stage: CameraProfile) -> dict[str, Any]:
    """The fresh image-only critics (:data:`~camdegrade.measures.critic.easier.FIT_CRITIC_SEEDS` seeds, each one
    critic per half of the validation scenes) of ``finished`` and ``with_stage`` on ``fit``'s validation pairs, both
    simulated with the fit's seed, and whether the stage is ``not_easier``: its critic at most
    :data:`~camdegrade.measures.critic.easier.CRITIC_SLACK` above the finished profile's. Not measurable (the
    critics ``None``, ``not_easier`` false) without :data:`~camdegrade.measures.critic.easier.MIN_CRITIC_SCENES`
    validation scenes."""
    scenes = list(fit.val.scenes) if fit.val_pairs else []
    counts = {"slack": CRITIC_SLACK, "scenes": len(set(scenes)), "needs": MIN_CRITIC_SCENES}
    if len(set(scenes)) < MIN_CRITIC_SCENES:
        return {"without": None, "with": None, "not_easier": False} | counts
    cleans, captures = (list(side) for side in zip(*fit.val_pairs, strict=True))
    rows = {}
    for label, profile in (("without", finished), ("with", with_stage)):
        sampled = profile.simulate(cleans, fit.seed, stream="mosaic-guard", eight_bit=fit.eight_bit)
        result = repeated_critic_test((cleans, captures, sampled), scenes, FIT_CRITIC_SEEDS, image_only=True)
        rows[label] = {"accuracy": round(result.accuracy, 4), "std": round(result.std, 4)}
    not_easier = critic_not_easier(rows["without"]["accuracy"], rows["with"]["accuracy"])
    return rows | {"not_easier": not_easier} | counts


def guard_line(guard: dict[str, Any]) -> str:
    """The guard's critics in words, for the fit's log."""
    if guard["with"] is None:
        return f"no critic ({guard['scenes']} validation scene(s); it needs {guard['needs']})"
    without, within = guard["without"], guard["with"]
    return (
        f"fresh image-only critic {without['accuracy']:.3f} ± {without['std']:.3f} without the stage, "
        f"{within['accuracy']:.3f} ± {within['std']:.3f} with the stage (slack {guard['slack']:.2f}): "
        f"{'no easier' if guard['not_easier'] else 'easier'}"
    )


def guard_kept(fit: PairedFit, before: CameraProfile, record: dict[str, Any], prefix: str) -> dict[str, Any]:
    """``record`` of a stage its form's distance kept in ``fit``'s profile (its noise refitted before it), judged
    by :func:`critic_guard` against ``before``: where the critic finds it easier, ``before`` is put back and the
    record says the stage was dropped and why. The log line starts with ``prefix``."""
    guard = critic_guard(fit, before, fit.profile)
    fit.say(f"{prefix}{guard_line(guard)} -> {'kept' if guard['not_easier'] else 'dropped'}")
    record = {**record, "critic": guard}
    if not guard["not_easier"]:
        fit.profile = before
        record |= {"kept": False, "reason": f"the form's distance closes, but {guard_line(guard)}"}
        record.pop("noise_refitted", None)
    return record
