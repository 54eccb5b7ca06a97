"""The network step of a paired fit: the least-squares linear baseline and the network trained on the training pairs
(through the sensor the resolution step found), judged on the validation pairs by what it gains over the clean image
passed through unchanged; a network that gains too little is dropped, and the profile holds its effect stages only.

References:
    Hegde et al., "A Simple Domain Shifting Network for Generating Low Quality Images" (the network and recipe).
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import torch

from camdegrade.effects import Resolution
from camdegrade.fitting.network.baseline import baseline_psnr, fit_linear_baseline
from camdegrade.fitting.network.training import EpochResult, fit_network, new_network
from camdegrade.fitting.recipe import FitConfig
from camdegrade.fitting.record import finite_or_none
from camdegrade.fitting.steps.base import FitStep, PairedFit, TrainedNetwork
from camdegrade.measures.metrics import psnr
from camdegrade.network import LocalAffineNet, ShiftNetwork
from camdegrade.pairs.pairset import ImagePair, PairSet
from camdegrade.profile import CameraProfile, as_profile

__all__ = ["NETWORK_MIN_GAIN_DB", "NetworkRun", "NetworkStep", "network_gain_db", "network_run", "validation_psnr"]

#: A fitted network is kept only when it (or the linear baseline) beats the clean image passed through unchanged by
#: at least this much validation PSNR; otherwise the profile holds its effect stages alone. On the real-noise pairs
#: of ``bench/bench_noise_gap.py`` (clean = the mean of many frames, so the camera's expected capture *is* the clean
#: image) the networks gained 0.04–0.09 dB on validation by fitting the training captures' exposure offsets, and a
#: denoiser trained on their output lost 0.07–0.18 dB on real held-out captures against the noise stage alone; a
#: camera with a lens, colour or tone effect gains whole dBs (City100: the clean image 23.8 dB, the network 30.4;
#: the half-bright camera of ``tests/test_network_drop.py``: more than 3 dB).
NETWORK_MIN_GAIN_DB = 0.2


@dataclass(frozen=True)
class NetworkRun:
    """How a fit's network trains: from ``initial`` (``init_from``'s network, recorded as ``label``) or from the
    recipe's seed, on ``device``, with a ``checkpoint`` (``resume`` from it), a ``callback`` after every epoch and a
    progress bar."""

    initial: ShiftNetwork | None = None
    label: str | None = None
    device: torch.device | str = "cpu"
    checkpoint: str | os.PathLike[str] | None = None
    resume: bool = False
    callback: Callable[[EpochResult], None] | None = None
    progress: bool = False


def network_run(
    init_from: CameraProfile | str | os.PathLike[str] | None, config: FitConfig, **how: Any
) -> tuple[NetworkRun, FitConfig]:
    """The run that ``init_from`` and ``how`` (:class:`NetworkRun`'s other fields) describe, checked before any pair
    is loaded, and the recipe it trains: a refit continues the network it starts from, whatever the recipe's
    ``arch``, ``upsample`` and ``curves``."""
    initial, label = _initial_network(init_from, config)
    scale = config.option("sensor_scale")
    if initial is not None and scale not in (None, "auto", 1, 1.0):
        raise ValueError(
            f"sensor_scale={scale} trains a new network through the sensor; init_from continues a "
            "network as it was trained: pass one or the other"
        )
    if initial is not None:
        config = config.replace(
            arch=initial.arch,
            upsample=getattr(initial, "upsample", None),
            curves="channel" if getattr(initial, "curves", False) else "none",
        )
    return NetworkRun(initial, label, **how), config


@dataclass(frozen=True)
class NetworkStep(FitStep):
    """The network step: ``propose`` fits the linear baseline and trains the network on the training pairs (a
    ``local_affine`` network starts from the baseline), ``judge`` keeps it where it, or the baseline, gains at least
    :data:`NETWORK_MIN_GAIN_DB` over the identity on the validation pairs (always without them). The record,
    ``fitted['network']``, says whether it was kept and the gains it was judged on; the fit keeps the trained
    network and its scores for the profile's quality record."""

    name: ClassVar[str] = "network"
    config: FitConfig
    how: NetworkRun

    def propose(self, fit: PairedFit) -> TrainedNetwork:
        config, run = self.config, self.how
        baseline_pairs = fit.train.images if fit.sensor is None else _through(fit.sensor, fit.train_pairs)
        baseline = fit_linear_baseline(baseline_pairs, seed=config.seed)
        initial = run.initial
        if initial is None and config.arch == LocalAffineNet.arch:
            initial = _from_baseline(config, baseline)
        names = [*fit.train.names, *fit.val.names]
        how = {key: getattr(run, key) for key in ("device", "callback", "checkpoint", "resume", "progress")}
        network, history = fit_network(
            fit.train.images, fit.val.images, config, pair_names=names, initial=initial, after=fit.sensor, **how
        )
        return TrainedNetwork(network, history, baseline, minutes=(time.perf_counter() - fit.started) / 60)

    def judge(self, fit: PairedFit, trained: TrainedNetwork) -> dict[str, Any]:
        trained.scores = validation_psnr(trained.network, trained.baseline, fit.val, fit.sensor)
        gain = network_gain_db(trained.scores)
        trained.kept = gain is None or gain["best"] >= NETWORK_MIN_GAIN_DB
        if not trained.kept:
            fit.say(
                f"network dropped: its gain over the clean image is {gain['network']:+.2f} dB on the "
                f"validation pairs (the linear baseline's {gain['baseline']:+.2f} dB), less than "
                f"{NETWORK_MIN_GAIN_DB} dB; the profile holds effect stages only"
            )
        profile = CameraProfile(
            trained.network if trained.kept else None, name=fit.profile.name, description=fit.profile.description
        )
        if fit.sensor is not None and trained.kept:
            profile = profile.with_effects(fit.sensor)
        elif fit.sensor is not None:
            fit.withdraw("resolution", "the network it was trained with was dropped")
        fit.profile, fit.network = profile, trained
        return network_note(trained.kept, gain)


def validation_psnr(
    network: ShiftNetwork,
    baseline: tuple[torch.Tensor, torch.Tensor],
    val: PairSet,
    sensor: Resolution | None = None,
) -> dict[str, float] | None:
    """Mean validation PSNR (dB) against the captures of the clean images unchanged (``identity``), the linear
    baseline and the trained network (both through ``sensor`` when the fit found one); ``None`` without validation
    pairs."""
    if not len(val):
        return None
    pairs = val.unit_pairs()
    network.eval()
    with torch.no_grad():
        identity = sum(psnr(clean, captured) for clean, captured in pairs) / len(pairs)
        outputs = [network(clean[None]) for clean, _ in pairs]
        if sensor is not None:
            outputs = [sensor(output) for output in outputs]
        predicted = sum(psnr(output[0], captured) for output, (_, captured) in zip(outputs, pairs)) / len(pairs)
    return {"identity": identity, "baseline": baseline_psnr(*baseline, pairs, sensor), "network": predicted}


def network_gain_db(scores: dict[str, float] | None) -> dict[str, float] | None:
    """The gain over the identity (dB) of the network, of the linear baseline and the better of the two, from
    :func:`validation_psnr`'s scores; ``None`` without them (nothing to judge on: the network is kept)."""
    if scores is None:
        return None
    # Captures identical to the clean images make the identity's PSNR infinite: no finite gain over it (-inf).
    gains = {key: scores[key] - scores["identity"] for key in ("network", "baseline")}
    gains = {key: -math.inf if math.isnan(gain) else gain for key, gain in gains.items()}
    return {key: round(value, 3) for key, value in {**gains, "best": max(gains.values())}.items()}


def network_note(kept: bool, gain: dict[str, float] | None) -> dict[str, Any]:
    """``fitted['network']``: whether the network was kept, and the validation gains it was judged on."""
    note: dict[str, Any] = {"kept": kept, "min_gain_db": NETWORK_MIN_GAIN_DB}
    if gain is not None:
        note["gain_db"] = gain["network"]
        note["baseline_gain_db"] = gain["baseline"]
    return finite_or_none(note)


def _through(sensor: Resolution, pairs: Sequence[ImagePair]) -> list[ImagePair]:
    """``pairs`` with each clean image passed through ``sensor``."""
    with torch.no_grad():
        return [(sensor(clean[None])[0], captured) for clean, captured in pairs]


def _from_baseline(config: FitConfig, baseline: tuple[torch.Tensor, torch.Tensor]) -> ShiftNetwork:
    """A fresh :class:`LocalAffineNet` (seeded) whose full-resolution filter is the least-squares baseline: the fit
    starts at the simple answer and can only keep or improve on it."""
    network = new_network(config)
    with torch.no_grad():
        network.linear.weight.copy_(baseline[0])
        network.linear.bias.copy_(baseline[1])
    return network


def _initial_network(
    init_from: CameraProfile | str | os.PathLike[str] | None, config: FitConfig
) -> tuple[ShiftNetwork | None, str | None]:
    """The network ``init_from`` names (checked before any pair is loaded) and how the metadata records it: the name
    or path as given, or a profile object's name."""
    if init_from is None:
        return None, None
    if not isinstance(init_from, (CameraProfile, str, os.PathLike)):
        raise TypeError(
            f"init_from must be a CameraProfile, a profile name, a path or None, got {type(init_from).__name__}"
        )
    profile = as_profile(init_from)
    label = (profile.name or "(unnamed profile)") if isinstance(init_from, CameraProfile) else os.fspath(init_from)
    if profile.network is None:
        raise ValueError(f"init_from: profile {label!r} has no network to start from (it holds effect stages only)")
    if profile.network.width != config.width:
        raise ValueError(
            f"init_from: profile {label!r} has a network of width {profile.network.width}; this fit's width is "
            f"{config.width}, so it cannot start from it (pass width={profile.network.width})"
        )
    return profile.network, label
