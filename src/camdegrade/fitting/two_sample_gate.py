"""Whether a learned texture stage is kept: trained on one half of the images, judged on the other half.

A learned stage is kept only where, on images it was not trained on,

- the set statistics the unpaired fit matches move closer to the captures': the RMS over the five spectrum bands'
  log2 power differences (:data:`~camdegrade.measures.fidelity.BAND_EDGES`, set means, centre crops) and the log2
  flat-noise ratio (each side's own flat pixels) together (:func:`statistics_distance`), and
- a *fresh* image-only critic (:func:`~camdegrade.measures.critic.repeated_critic_test`, never the critic the stage
  was trained against, which it learned to fool) does not tell the simulation from the captures more easily than
  without the stage (by more than :data:`CRITIC_SLACK`).

Both directions are judged (trained on half A, judged on half B, and back); the stage kept is then trained on all
images. :func:`fit_learned_stage` runs it; :func:`judge_learned_stage` is one judgement.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import torch
from torch import Tensor

from camdegrade.effects import LearnedTexture
from camdegrade.effects.base import evenly_spaced
from camdegrade.fitting.two_sample import TwoSampleOptions, fit_two_sample
from camdegrade.fitting.unpaired.noise import flat_sums
from camdegrade.fitting.unpaired.spectrum import SPECTRUM_SIDE, centre_crop
from camdegrade.measures.critic import PATCH, repeated_critic_test
from camdegrade.measures.fidelity import band_power
from camdegrade.profile import CameraProfile

__all__ = ["CRITIC_SLACK", "Judgement", "fit_learned_stage", "judge_learned_stage", "statistics_distance"]

#: A judgement uses at most this many held-out clean images and as many captures (evenly spaced): its critics and
#: simulations are most of the gate's time, and 16 City100 scenes already separate the rows of docs/results.md.
JUDGE_IMAGES = 20
#: How much easier the fresh critic may find the simulation with the stage (accuracy; its critics' own spread on
#: 8 held-out scenes is about 0.05, docs/results.md).
CRITIC_SLACK = 0.02


@dataclass
class Judgement:
    """One held-out judgement: the statistics and the fresh critic without and with the stage."""

    without: dict[str, Any]
    with_stage: dict[str, Any]
    closer: bool
    critic_not_easier: bool
    keep: bool = field(init=False)

    def __post_init__(self) -> None:
        self.keep = self.closer and self.critic_not_easier

    def to_dict(self) -> dict[str, Any]:
        return {
            "without": self.without,
            "with": self.with_stage,
            "closer": self.closer,
            "critic_not_easier": self.critic_not_easier,
            "keep": self.keep,
        }


def set_statistics(images: Sequence[Tensor], captures: Sequence[Tensor]) -> dict[str, Any]:
    """``images`` against ``captures`` (other scenes allowed): the set means' log2 band power differences on centre
    crops of :data:`SPECTRUM_SIDE`, and the flat-noise ratio, each set's own flat pixels
    (:func:`~camdegrade.fitting.unpaired.noise.flat_sums`)."""

    def bands(side: Sequence[Tensor]) -> Tensor:
        powers = [band_power(centre_crop(image, SPECTRUM_SIDE))[0] for image in side]
        return torch.stack(powers).clamp_min(1e-8).log2().mean(0)

    real_std = flat_sums(list(captures)).pooled_std()
    ratio = flat_sums(list(images)).pooled_std() / real_std if real_std > 0 else math.nan
    return {
        "bands": [round(float(value), 3) for value in bands(images) - bands(captures)],
        "noise_ratio": round(ratio, 3) if math.isfinite(ratio) else None,
    }


def statistics_distance(statistics: dict[str, Any]) -> float:
    """The RMS of the band differences and the log2 noise ratio (all log2 units; 0: the captures' statistics)."""
    parts = list(statistics["bands"])
    if statistics["noise_ratio"] is not None:
        parts.append(math.log2(statistics["noise_ratio"]))
    return math.sqrt(sum(value * value for value in parts) / len(parts))


def _triples(cleans: Sequence[Tensor], captures: Sequence[Tensor]) -> tuple[list[Tensor], list[Tensor]]:
    """Each clean image with a capture (in turn), both cropped to their common size: the critic's patches are cut at
    the same places of the capture and of the clean image's simulation (the scenes differ: unpaired)."""
    kept_cleans, kept_captures = [], []
    for index, clean in enumerate(cleans):
        capture = captures[index % len(captures)]
        height = min(clean.shape[-2], capture.shape[-2])
        width = min(clean.shape[-1], capture.shape[-1])
        if min(height, width) >= PATCH:
            kept_cleans.append(clean[:, :height, :width])
            kept_captures.append(capture[:, :height, :width])
    return kept_cleans, kept_captures


def judge_learned_stage(
    named: CameraProfile,
    stage: LearnedTexture,
    cleans: Sequence[Tensor],
    captures: Sequence[Tensor],
    *,
    seed: int = 0,
    critic_seeds: int = 2,
    statistics_slack: float = 0.0,
) -> Judgement:
    """Judge ``stage`` after ``named`` on held-out ``cleans`` and ``captures`` (at most :data:`JUDGE_IMAGES` of
    each; :class:`Judgement`). ``statistics_slack``: how much farther (RMS log2) the statistics may move and still
    count as closer (0: the rule of the named stages; on City100 a stage that took the fresh critic from 0.73 to
    0.64 moved them 0.03 farther, docs/results.md)."""
    cleans, captures = _triples(evenly_spaced(cleans, JUDGE_IMAGES), evenly_spaced(captures, JUDGE_IMAGES))
    scenes = [f"{index:04d}" for index in range(len(cleans))]
    rows = {}
    for label, profile in (("without", named), ("with", named.with_effects(stage))):
        sims = profile.simulate(cleans, seed, stream="two-sample-gate", eight_bit=True)
        statistics = set_statistics(sims, captures)
        critic = repeated_critic_test((cleans, captures, sims), scenes, critic_seeds, image_only=True)
        rows[label] = {
            **statistics,
            "distance": round(statistics_distance(statistics), 4),
            "critic": round(critic.accuracy, 4),
            "critic_std": round(critic.std, 4),
        }
    return Judgement(
        without=rows["without"],
        with_stage=rows["with"],
        closer=rows["with"]["distance"] < rows["without"]["distance"] + statistics_slack,
        critic_not_easier=rows["with"]["critic"] <= rows["without"]["critic"] + CRITIC_SLACK,
    )


def fit_learned_stage(
    named: CameraProfile,
    cleans: Sequence[Tensor],
    captures: Sequence[Tensor],
    *,
    seed: int = 0,
    steps: int = 1200,
    options: TwoSampleOptions | None = None,
    critic_seeds: int = 2,
    statistics_slack: float = 0.0,
    progress: bool = False,
) -> tuple[LearnedTexture | None, dict[str, Any]]:
    """A learned texture stage after ``named``, or ``None`` where the held-out halves do not keep it.

    The images alternate between halves A and B; a stage trained on A is judged on B and one trained on B on A
    (:func:`judge_learned_stage`; once one is refused the other is not trained); where both keep theirs, the stage
    returned is trained on all the images. The evidence holds the judgements and every training's record.
    """
    halves = [slice(0, None, 2), slice(1, None, 2)]
    judgements, trainings = [], []
    for fit, held in (halves, halves[::-1]):
        stage, record = fit_two_sample(
            named, cleans[fit], captures[fit], seed=seed, steps=steps, options=options, progress=progress
        )
        trainings.append(record)
        judgements.append(
            judge_learned_stage(
                named,
                stage,
                cleans[held],
                captures[held],
                seed=seed,
                critic_seeds=critic_seeds,
                statistics_slack=statistics_slack,
            )
        )
        if not judgements[-1].keep:
            break
    kept = len(judgements) == 2 and all(judgement.keep for judgement in judgements)
    final = None
    if kept:
        final, record = fit_two_sample(
            named, list(cleans), list(captures), seed=seed, steps=steps, options=options, progress=progress
        )
        trainings.append(record)
    evidence = {"kept": kept, "judgements": [j.to_dict() for j in judgements], "trainings": trainings}
    return final, evidence
