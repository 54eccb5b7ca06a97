"""The critic on one set of pairs, split by scene: one critic per half scoring the other, repeated over seeds, and
the spread of what they read (a fit's own validation pairs have no held-out part of their own)."""

from __future__ import annotations

import math
import statistics
import time
from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import Tensor

from camdegrade.measures.critic.core import (
    BATCH,
    STEPS,
    CriticResult,
    bootstrap_interval,
    critic_test,
    logits,
    train_critic,
)
from camdegrade.measures.critic.patches import PATCH, PATCHES_PER_PAIR, Patches, pair_features

__all__ = ["SPLIT_PASSES", "CriticSpread", "alternate_scenes", "repeated_critic_test", "split_critic_test"]

#: :func:`split_critic_test` trains for this many passes over its training patches (at most :data:`STEPS` steps):
#: a fit's few validation scenes give a few hundred patches, which 250 steps would show 40 times over.
SPLIT_PASSES = 25


def split_critic_test(
    pairs: tuple[Sequence[Tensor], Sequence[Tensor], Sequence[Tensor]],
    scenes: Sequence[str],
    seed: int,
    steps: int | None = None,
    image_only: bool = False,
) -> CriticResult:
    """:func:`critic_test` on one set of ``pairs`` = (cleans, reals, sims) with no held-out part of its own (a fit's
    validation pairs): their ``scenes``, in sorted order, alternate between training the critic and scoring it, so
    no scene is on both sides. ``steps``: by default :data:`SPLIT_PASSES` passes over the training patches, at most
    :data:`STEPS`. Few scenes make a noisy critic: read its bootstrap interval.

    Raises:
        ValueError: fewer than two scenes, or no pair of at least :data:`PATCH` pixels on either side.
    """
    _check_scenes(pairs, scenes)
    trains = alternate_scenes(scenes)
    calibration = tuple([item for item, chosen in zip(column, trains, strict=True) if chosen] for column in pairs)
    held_out = tuple([item for item, chosen in zip(column, trains, strict=True) if not chosen] for column in pairs)
    return critic_test(calibration, held_out, seed, steps or _split_steps(calibration[0]), image_only)


def _split_steps(cleans: Sequence[Tensor]) -> int:
    """:data:`SPLIT_PASSES` passes over the patches of the pairs of ``cleans``, at most :data:`STEPS` steps."""
    patches = 2 * PATCHES_PER_PAIR * sum(min(clean.shape[-2:]) >= PATCH for clean in cleans)
    return max(1, min(STEPS, math.ceil(SPLIT_PASSES * patches / BATCH)))


def _check_scenes(pairs: tuple[Sequence[Tensor], ...], scenes: Sequence[str]) -> None:
    names = set(scenes)
    if len(names) < 2 or len(scenes) != len(pairs[0]):
        raise ValueError(
            f"the critic needs pairs of at least two scenes (one side trains it, the other scores it), got "
            f"{len(names)} scene(s) for {len(pairs[0])} pair(s)"
        )


@dataclass
class CriticSpread:
    """Several critics on one set of pairs (:func:`repeated_critic_test`): how well they tell the real captures
    from the simulations, and how much that depends on the critic.

    ``accuracy`` is pooled over every critic's held-out patches; ``low``–``high`` the 95 % interval of it by a
    bootstrap over the pairs (each pair's accuracy averaged over the critics that scored it); ``std`` the standard
    deviation of the critics' own accuracies (``accuracies``, two per seed: one per half of the scenes).
    ``patches``: held-out patches per seed (both halves), ``pairs``: the pairs they come from."""

    accuracy: float
    low: float
    high: float
    std: float
    accuracies: tuple[float, ...]
    patches: int
    pairs: int
    seconds: float

    def to_dict(self, digits: int = 3) -> dict:
        """The numbers, rounded, as a profile's ``quality`` stores them."""
        out = {key: round(getattr(self, key), digits) for key in ("accuracy", "low", "high", "std")}
        return out | {
            "critics": len(self.accuracies),
            "accuracies": [round(value, digits) for value in self.accuracies],
            "patches": self.patches,
            "pairs": self.pairs,
        }

    def describe(self) -> str:
        return (
            f"critic accuracy {self.accuracy:.2f} ± {self.std:.2f} over {len(self.accuracies)} critics "
            f"({min(self.accuracies):.2f}–{max(self.accuracies):.2f}) [95 % CI {self.low:.2f}–{self.high:.2f}] on "
            f"{self.pairs} pairs"
        )


def repeated_critic_test(
    pairs: tuple[Sequence[Tensor], Sequence[Tensor], Sequence[Tensor]],
    scenes: Sequence[str],
    seeds: int,
    steps: int | None = None,
    image_only: bool = False,
) -> CriticSpread:
    """:func:`split_critic_test` repeated: for each seed in ``range(seeds)``, one critic trained on each half of the
    scenes (:func:`alternate_scenes`) and scored on the other half, so every pair is scored ``seeds`` times by
    critics that never saw its scene. One critic either finds what tells a simulation from its camera or does not
    (8 critics of the City100 built-in, image only: 0.70 to 0.83; docs/results.md): the mean and the spread of
    several are the measurement.

    Raises:
        ValueError: fewer than two scenes, ``seeds`` below 1, or no pair of at least :data:`PATCH` pixels on a side.
    """
    _check_scenes(pairs, scenes)
    if isinstance(seeds, bool) or not isinstance(seeds, int) or seeds < 1:
        raise ValueError(f"seeds must be a positive integer, got seeds={seeds!r}")
    started = time.perf_counter()
    trains = alternate_scenes(scenes)
    first = [index for index, chosen in enumerate(trains) if chosen]
    second = [index for index, chosen in enumerate(trains) if not chosen]
    correct_sum, count = torch.zeros(len(scenes)), torch.zeros(len(scenes))
    accuracies = []
    features = [pair_features(*pair) if min(pair[0].shape[-2:]) >= PATCH else None for pair in zip(*pairs, strict=True)]
    for seed in range(seeds):
        for fit, held in ((first, second), (second, first)):
            calibration = tuple([column[index] for index in fit] for column in pairs)
            scored = tuple([column[index] for index in held] for column in pairs)
            fit_features, held_features = [features[i] for i in fit], [features[i] for i in held]
            patches_in = Patches.sample(*calibration, seed, "critic-calibration", image_only, fit_features)
            net = train_critic(patches_in, seed, steps or _split_steps(calibration[0]))
            patches = Patches.sample(*scored, seed, "critic-held-out", image_only, held_features)
            correct = ((logits(net, patches) > 0).float() == patches.labels).float()
            accuracies.append(float(correct.mean()))
            owner = torch.tensor(held)[patches.pair]
            correct_sum.index_add_(0, owner, correct)
            count.index_add_(0, owner, torch.ones_like(correct))
    used = count > 0
    low, high = bootstrap_interval(correct_sum[used] / count[used], count[used], 0)
    return CriticSpread(
        accuracy=float(correct_sum.sum() / count.sum()),
        low=low,
        high=high,
        std=statistics.stdev(accuracies) if len(accuracies) > 1 else 0.0,
        accuracies=tuple(accuracies),
        patches=int(count.sum()) // seeds,
        pairs=int(used.sum()),
        seconds=time.perf_counter() - started,
    )


def alternate_scenes(scenes: Sequence[str]) -> list[bool]:
    """For each pair of ``scenes`` (its scene id), whether it trains a critic (True) or scores it: the scenes in
    sorted order alternate between the two, so no scene is on both sides. With a single scene, the pairs alternate
    instead (its pairs still differ, though less than scenes would)."""
    names = sorted(set(scenes))
    if len(names) < 2:
        return [index % 2 == 0 for index in range(len(scenes))]
    return [names.index(scene) % 2 == 0 for scene in scenes]
