"""A fit as a loop of steps. A :class:`FitStep` proposes something from the data it fits on (a stage, a sensor, a
network), judges it on data it was not fitted on (the validation pairs of a paired fit; halves of the sets in the
unpaired fit), and returns its evidence record: kept or not, and why. :func:`run_steps` is the loop both fits run;
the fit in progress (:class:`PairedFit`, or the unpaired fit's bench) holds the profile so far and the records, and
says why a step cannot run."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, fields
from functools import cached_property
from typing import Any, ClassVar, Protocol

import torch
from torch import Tensor

from camdegrade.effects import Effect, Resolution
from camdegrade.network import ShiftNetwork
from camdegrade.pairs.pairset import ImagePair, PairSet
from camdegrade.profile import CameraProfile

__all__ = ["FitStep", "PairedFit", "TrainedNetwork", "Verdict", "closes_gap", "keep_and_refit_noise", "run_steps"]

Log = Callable[[str], None]
#: A step's evidence record, written to the fit's records under the step's name.
Record = dict[str, Any]


@dataclass(frozen=True)
class Verdict:
    """A step's evidence decided without a judge: nothing to judge was fitted (too few pixels, no candidate better
    than none, a stage the profile has already), so ``propose`` returns the record itself."""

    record: Record


class FitStep:
    """One step of a fit; subclasses are frozen dataclasses whose fields are the step's options.

    :meth:`propose` fits on the training data and returns a proposal (or a :class:`Verdict`); :meth:`judge` decides
    on held-out data whether to keep it, puts what it keeps into the fit, and returns the evidence record (``None``:
    nothing to record). :meth:`run` is the two in turn; a step that is several steps in one (each effect stage)
    runs them itself.
    """

    #: The key of the step's record (``fitted[name]`` of a paired fit).
    name: ClassVar[str]
    #: A step that fits on top of a network: without one it records ``"no network"`` (paired fits).
    needs_network: ClassVar[bool] = False
    #: The network is trained through what this step finds, so it runs before the network.
    before_network: ClassVar[bool] = False

    def check(self, recipe: Any) -> None:
        """Refuse options that do not suit ``recipe`` (a :class:`~camdegrade.fitting.FitConfig`) with a
        ``ValueError``; the table's rules for each option are checked already."""

    def propose(self, fit: Any) -> Any:
        raise NotImplementedError

    def judge(self, fit: Any, proposal: Any) -> Record | None:
        raise NotImplementedError

    def run(self, fit: Any) -> Record | None:
        proposal = self.propose(fit)
        return proposal.record if isinstance(proposal, Verdict) else self.judge(fit, proposal)

    def options(self) -> dict[str, Any]:
        """The step's options by name."""
        return {option.name: getattr(self, option.name) for option in fields(self)}  # type: ignore[arg-type]


class Bench(Protocol):
    """What the loop needs of a fit in progress."""

    records: dict[str, Any]

    def keep(self, kept: bool, *stages: Effect) -> None:
        """The profile with ``stages`` added where a judge ``kept`` them."""
        if kept:
            self.profile = self.profile.with_effects(*stages)

    def unmet(self, step: FitStep) -> str | None: ...

    def skip(self, step: FitStep, reason: str) -> None: ...


def closes_gap(real: float, without: float, within: float, tolerance: float, share: float) -> bool:
    """Whether a stage brings a statistic of the simulation (``without`` it, ``within`` with it) to the captures'
    ``real``: what it leaves is below ``tolerance`` or at most ``1 − share`` of the gap it found."""
    left = abs(real - within)
    return left < tolerance or left <= (1 - share) * abs(real - without)


def keep_and_refit_noise(
    fit: PairedFit,
    name: str,
    judged: tuple[Effect | None, dict[str, Any], str],
    note: dict[str, Any],
    refit_noise: Callable[[PairedFit], str | None],
    refitted: str,
) -> dict[str, Any]:
    """The record of an evidence stage ``name`` judged as ``judged`` (the stage kept or ``None``, its record, its
    line), after its proposal's ``note``: a kept stage goes into ``fit``'s profile and the noise stage before it is
    refitted by ``refit_noise`` (a stage that moves the noise's statistics, as a codec or a demosaic does); the
    record says whether its line holds ``refitted``."""
    kept, record, line = judged
    fit.say(f"effect {name}: {line}")
    record = {**note, **record}
    if kept is not None:
        fit.keep(True, kept)
        line = refit_noise(fit)
        if line is not None:
            fit.say(line)
            record["noise_refitted"] = refitted in line
    return record


def run_steps(steps: Iterable[FitStep], fit: Bench) -> None:
    """Run ``steps`` in order on ``fit``: each step's record goes to ``fit.records[step.name]``; a step the fit says
    it cannot run (:meth:`Bench.unmet`) is skipped with that reason."""
    for step in steps:
        reason = fit.unmet(step)
        if reason is not None:
            fit.skip(step, reason)
        else:
            record = step.run(fit)
            if record is not None:
                fit.records[step.name] = record


@dataclass
class TrainedNetwork:
    """What a paired fit's network step leaves for the record: the network, its training history
    (:class:`~camdegrade.fitting.EpochResult` per epoch), the linear baseline, the validation scores (PSNR of the
    identity, the baseline and the network; ``None`` without validation pairs), whether the profile kept it, and the
    minutes from the start of the fit to the end of its training."""

    network: ShiftNetwork
    history: Sequence[Any]
    baseline: tuple[Tensor, Tensor]
    minutes: float
    scores: dict[str, float] | None = None
    kept: bool = True


@dataclass
class PairedFit:
    """A paired fit in progress: the training and validation pairs, the profile so far, the sensor the network is
    trained through (the resolution step's), the trained network once there is one, and every step's record.

    ``arch`` is the network the recipe trains and ``refit`` whether it continues one (``init_from``): what the steps
    before the network need to know of it."""

    train: PairSet
    val: PairSet
    profile: CameraProfile
    seed: int
    say: Log
    eight_bit: bool = False
    arch: str = "local_affine"
    refit: bool = False
    records: dict[str, Any] = field(default_factory=dict)
    sensor: Resolution | None = None
    network: TrainedNetwork | None = None
    started: float = field(default_factory=time.perf_counter)

    @classmethod
    def of(cls, pairs: PairSet, train: PairSet, val: PairSet, **values: Any) -> PairedFit:
        """The fit of ``train`` and ``val``, parts of ``pairs``; 8-bit when every capture of ``pairs`` is."""
        eight_bit = all(captured.dtype == torch.uint8 for _, captured in pairs.images)
        return cls(train, val, eight_bit=eight_bit, **values)

    @cached_property
    def train_pairs(self) -> list[ImagePair]:
        """The training pairs as float32 in [0, 1]."""
        return self.train.unit_pairs()

    @cached_property
    def val_pairs(self) -> list[ImagePair]:
        """The validation pairs as float32 in [0, 1]."""
        return self.val.unit_pairs()

    @property
    def evidence_pairs(self) -> tuple[list[ImagePair], str]:
        """The pairs a step is judged on and their name in its record: the validation pairs, or the training pairs
        without any."""
        return (self.val_pairs, "validation") if self.val_pairs else (self.train_pairs, "training")

    def judge_pairs(self, count: int) -> list[ImagePair]:
        """At most ``count`` of :attr:`evidence_pairs`."""
        return list(self.evidence_pairs[0])[:count]

    def keep(self, kept: bool, *stages: Effect) -> None:
        """The profile with ``stages`` added where a judge ``kept`` them."""
        if kept:
            self.profile = self.profile.with_effects(*stages)

    def unmet(self, step: FitStep) -> str | None:
        return "no network" if step.needs_network and self.profile.network is None else None

    def skip(self, step: FitStep, reason: str) -> None:
        self.records[step.name] = {"kept": False, "reason": reason}

    def withdraw(self, name: str, reason: str) -> None:
        """Mark the kept step ``name`` dropped after all, for ``reason`` (its stage went with a later decision)."""
        self.records[name] = {**self.records[name], "kept": False, "reason": reason}
