"""A fit step run on its own: a paired fit of given training and validation pairs around a profile."""

from __future__ import annotations

from collections.abc import Callable, Sequence

from torch import Tensor

from camdegrade import CameraProfile
from camdegrade.fitting.steps import FitStep, PairedFit
from camdegrade.pairs import PairSet


def paired_fit(
    profile: CameraProfile,
    train: Sequence[tuple[Tensor, Tensor]],
    val: Sequence[tuple[Tensor, Tensor]],
    say: Callable[[str], None] = lambda _: None,
    seed: int = 0,
) -> PairedFit:
    """A fit in progress on ``train`` and ``val`` (float pairs in [0, 1]; ``val`` may be empty) at ``profile``."""
    training = PairSet.load(list(train))
    held = PairSet.load(list(val)) if len(val) else PairSet([], [], [])
    return PairedFit.of(training, training, held, profile=profile, seed=seed, say=say, arch="local_affine", refit=False)


def run_step(
    step: FitStep,
    profile: CameraProfile,
    train: Sequence[tuple[Tensor, Tensor]],
    val: Sequence[tuple[Tensor, Tensor]],
    say: Callable[[str], None] = lambda _: None,
    seed: int = 0,
) -> tuple[CameraProfile, dict]:
    """``step`` run on a fit of ``train`` and ``val`` at ``profile``: the profile it leaves, and its record."""
    fit = paired_fit(profile, train, val, say, seed)
    record = step.run(fit)
    return fit.profile, record
