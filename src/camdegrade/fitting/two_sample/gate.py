"""The unpaired fit's last step: a learned texture stage (:func:`~camdegrade.fitting.two_sample.train.fit_two_sample`)
after the named stages, trained on one half of the sets and judged on the other, both ways.

Two measures judge a learned stage on images it was not trained on: a *fresh* image-only critic
(:func:`~camdegrade.measures.critic.repeated_critic_test`, never the critic the stage was trained against, which it
learned to fool), and the set statistics the named stages matched (the RMS over the five spectrum bands' log2 power
differences and the log2 flat-noise ratio, :func:`statistics_distance`). It is kept where it makes neither worse and
one better:

- the statistics move farther from the captures' by no more than the content of the judging images alone moves
  that change (:data:`~camdegrade.fitting.unpaired.judges.SIGNIFICANCE` split-half standard errors,
  :func:`~camdegrade.fitting.unpaired.judges.split_half_error`: the named stages' own rule of what a change is);
- the fresh critic finds it no easier (by :data:`CRITIC_SLACK`);
- and the critic falls, or the statistics move closer by more than that error.

A rule of "closer" without the error refused City100's stage for 0.012 and 0.027 log2 (1.4 and 2.3 standard
errors; the critic fell 0.68 → 0.62 and 0.77 → 0.66): the stage takes about 0.08 log2 off the 0.25–0.35
cycles/pixel band, a change the named stages' judges would not call one (docs/results.md).

Both directions are judged (trained on half A, judged on half B, and back; once one is refused the other is not
trained); the stage kept is then trained on all images. :func:`fit_learned_stage` does it for any profile; the
unpaired fit's step (:mod:`camdegrade.fitting.two_sample.step`) does it in three parts.
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
from camdegrade.fitting.two_sample.train import TwoSampleOptions, fit_two_sample
from camdegrade.fitting.unpaired.judges import SIGNIFICANCE, common_crops, split_half_error
from camdegrade.fitting.unpaired.steps.noise import flat_sums
from camdegrade.fitting.unpaired.steps.spectrum import SPECTRUM_SIDE, centre_crop
from camdegrade.functional.analysis.noise import NoiseSums
from camdegrade.measures.critic import repeated_critic_test
from camdegrade.measures.critic.easier import CRITIC_SLACK, critic_not_easier
from camdegrade.measures.fidelity import band_power
from camdegrade.profile import CameraProfile

__all__ = [
    "CRITIC_SLACK",
    "HALVES",
    "JUDGE_IMAGES",
    "ImageStatistics",
    "Judgement",
    "StageTraining",
    "critic_not_easier",
    "fit_learned_stage",
    "judge_half",
    "judge_halves",
    "judge_learned_stage",
    "kept_stage",
    "measured_statistics",
    "set_statistics",
    "statistics_distance",
]

#: A judgement uses at most this many held-out clean images and as many captures (evenly spaced): its critics are
#: most of its time, and 16 City100 scenes already separate the rows of docs/results.md.
JUDGE_IMAGES = 20


@dataclass(frozen=True)
class StageTraining:
    """How a learned stage is trained and judged: the seed of both, the training's steps and options
    (:func:`~camdegrade.fitting.two_sample.train.fit_two_sample`), and the fresh critic's seeds (two critics each)."""

    seed: int = 0
    steps: int = 1200
    options: TwoSampleOptions | None = None
    critic_seeds: int = 2

    def train(
        self, named: CameraProfile, cleans: Sequence[Tensor], captures: Sequence[Tensor]
    ) -> tuple[LearnedTexture, dict[str, Any]]:
        """A stage after ``named`` trained on ``cleans`` and ``captures``, and its training record."""
        return fit_two_sample(named, cleans, captures, seed=self.seed, steps=self.steps, options=self.options)


@dataclass
class Judgement:
    """One held-out judgement: the statistics and the fresh critic without and with the stage, and the standard
    error of the statistics' change from split halves of the judging images."""

    without: dict[str, Any]
    with_stage: dict[str, Any]
    change_error: float
    not_farther: bool = field(init=False)
    not_easier: bool = field(init=False)
    better: bool = field(init=False)
    keep: bool = field(init=False)

    def __post_init__(self) -> None:
        change = self.with_stage["distance"] - self.without["distance"]
        critic_change = self.with_stage["critic"] - self.without["critic"]
        self.not_farther = change <= SIGNIFICANCE * self.change_error
        self.not_easier = critic_not_easier(self.without["critic"], self.with_stage["critic"])
        self.better = critic_change < 0 or change < -SIGNIFICANCE * self.change_error
        self.keep = self.not_farther and self.not_easier and self.better

    def to_dict(self) -> dict[str, Any]:
        return {
            "without": self.without,
            "with": self.with_stage,
            "change_error": round(self.change_error, 4),
            "not_farther": self.not_farther,
            "not_easier": self.not_easier,
            "better": self.better,
            "keep": self.keep,
        }


@dataclass(frozen=True)
class ImageStatistics:
    """What :func:`set_statistics` reads of one image: its centre crop's band power and its flat-pixel noise sums.
    Measured once per image, a set's statistics are their sums, whichever part of a set is asked for (the
    split-half error asks for 32 parts of the same images)."""

    power: Tensor
    noise: NoiseSums

    @classmethod
    def of(cls, image: Tensor) -> ImageStatistics:
        return cls(band_power(centre_crop(image, SPECTRUM_SIDE))[0], flat_sums([image]))


def set_statistics(images: Sequence[Tensor], captures: Sequence[Tensor]) -> dict[str, Any]:
    """``images`` against ``captures`` (other scenes allowed): the set means' log2 band power differences on centre
    crops of :data:`SPECTRUM_SIDE`, and the flat-noise ratio, each set's own flat pixels
    (:func:`~camdegrade.fitting.unpaired.steps.noise.flat_sums`)."""
    measured = [[ImageStatistics.of(image) for image in side] for side in (images, captures)]
    return measured_statistics(*measured)


def measured_statistics(images: Sequence[ImageStatistics], captures: Sequence[ImageStatistics]) -> dict[str, Any]:
    """:func:`set_statistics` of images measured already (the same numbers: the same sums in the same order)."""

    def bands(side: Sequence[ImageStatistics]) -> Tensor:
        return torch.stack([image.power for image in side]).clamp_min(1e-8).log2().mean(0)

    def noise(side: Sequence[ImageStatistics]) -> NoiseSums:
        total = NoiseSums.zeros()
        for image in side:
            total = total + image.noise
        return total

    real_std = noise(captures).pooled_std()
    ratio = noise(images).pooled_std() / real_std if real_std > 0 else math.nan
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


def _change_error(
    without: list[ImageStatistics], with_stage: list[ImageStatistics], captures: list[ImageStatistics], seed: int
) -> float:
    """The split-half standard error of the statistics' change (with the stage less without) over the judging
    images: how much their content alone moves it."""

    def change(capture_part: list[int], clean_part: list[int]) -> Tensor:
        reals = [captures[index] for index in capture_part]
        distances = [
            statistics_distance(measured_statistics([sims[index] for index in clean_part], reals))
            for sims in (without, with_stage)
        ]
        return torch.tensor([distances[1] - distances[0]])

    return float(split_half_error(change, len(captures), len(without), seed)[0])


def judge_learned_stage(
    named: CameraProfile,
    stage: LearnedTexture,
    cleans: Sequence[Tensor],
    captures: Sequence[Tensor],
    *,
    seed: int = 0,
    critic_seeds: int = 2,
) -> Judgement:
    """Judge ``stage`` after ``named`` on held-out ``cleans`` and ``captures`` (at most :data:`JUDGE_IMAGES` of
    each; :class:`Judgement`)."""
    cleans, captures = common_crops(evenly_spaced(cleans, JUDGE_IMAGES), evenly_spaced(captures, JUDGE_IMAGES))
    scenes = [f"{index:04d}" for index in range(len(cleans))]
    rows, measured = {}, {}
    real = [ImageStatistics.of(image) for image in captures]
    for label, profile in (("without", named), ("with", named.with_effects(stage))):
        sims = profile.simulate(cleans, seed, stream="two-sample-gate", eight_bit=True)
        measured[label] = [ImageStatistics.of(image) for image in sims]
        statistics = measured_statistics(measured[label], real)
        critic = repeated_critic_test((cleans, captures, sims), scenes, critic_seeds, image_only=True)
        rows[label] = {
            **statistics,
            "distance": round(statistics_distance(statistics), 4),
            "critic": round(critic.accuracy, 4),
            "critic_std": round(critic.std, 4),
        }
    error = _change_error(measured["without"], measured["with"], real, seed)
    return Judgement(without=rows["without"], with_stage=rows["with"], change_error=error)


#: The two halves of the fitting images (alternate ones), A and B.
HALVES = (slice(0, None, 2), slice(1, None, 2))


def judge_half(
    named: CameraProfile,
    cleans: Sequence[Tensor],
    captures: Sequence[Tensor],
    training: StageTraining,
    fit: slice,
    held: slice,
) -> tuple[Judgement, dict[str, Any]]:
    """A stage after ``named`` trained on the ``fit`` part of the images and judged on the ``held`` part, and the
    training's record."""
    cleans, captures = list(cleans), list(captures)
    stage, record = training.train(named, cleans[fit], captures[fit])
    judgement = judge_learned_stage(
        named, stage, cleans[held], captures[held], seed=training.seed, critic_seeds=training.critic_seeds
    )
    return judgement, record


def judge_halves(
    named: CameraProfile, cleans: Sequence[Tensor], captures: Sequence[Tensor], training: StageTraining
) -> tuple[list[Judgement], list[dict[str, Any]]]:
    """Train a stage after ``named`` on half A of the images (:data:`HALVES`) and judge it on half B, then back
    (not once the first is refused): the judgements and the trainings' records."""
    judgements, trainings = [], []
    for fit, held in (HALVES, HALVES[::-1]):
        judgement, record = judge_half(named, cleans, captures, training, fit, held)
        judgements.append(judgement)
        trainings.append(record)
        if not judgement.keep:
            break
    return judgements, trainings


def fit_learned_stage(
    named: CameraProfile,
    cleans: Sequence[Tensor],
    captures: Sequence[Tensor],
    training: StageTraining | None = None,
) -> tuple[LearnedTexture | None, dict[str, Any]]:
    """A learned texture stage after ``named``, or ``None`` where the held-out halves do not keep it
    (:func:`judge_halves`); the stage kept is trained on all the images. The evidence holds the judgements and
    every training's record. ``training`` defaults to :class:`StageTraining`'s defaults."""
    cleans, captures, training = list(cleans), list(captures), training or StageTraining()
    return kept_stage(named, cleans, captures, judge_halves(named, cleans, captures, training), training)


def kept_stage(
    named: CameraProfile,
    cleans: Sequence[Tensor],
    captures: Sequence[Tensor],
    judged: tuple[list[Judgement], list[dict[str, Any]]],
    training: StageTraining,
) -> tuple[LearnedTexture | None, dict[str, Any]]:
    """The stage trained on all the images where both ``judged`` halves keep theirs (else ``None``), and the
    evidence: whether kept, the judgements, every training's record."""
    judgements, trainings = judged
    kept = len(judgements) == 2 and all(judgement.keep for judgement in judgements)
    final = None
    if kept:
        final, record = training.train(named, cleans, captures)
        trainings = [*trainings, record]
    return final, {"kept": kept, "judgements": [j.to_dict() for j in judgements], "trainings": trainings}
