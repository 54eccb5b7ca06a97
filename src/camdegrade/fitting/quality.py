"""How close a paired fit's profile comes to the camera on the validation pairs: PSNR of the identity, the linear
baseline, the network and the sampled profile; the fidelity numbers and a critic
(:mod:`camdegrade.measures.fidelity`, :mod:`camdegrade.measures.critic`); and what those scores warn about."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import torch

from camdegrade.fitting.network.training import EpochResult
from camdegrade.fitting.recipe import FitConfig
from camdegrade.fitting.steps.noise_evidence import as_stored
from camdegrade.measures.critic import repeated_critic_test
from camdegrade.measures.critic.easier import FIT_CRITIC_SEEDS, MIN_CRITIC_SCENES
from camdegrade.measures.fidelity import measure_fidelity
from camdegrade.measures.metrics import psnr
from camdegrade.pairs.pairset import PairSet
from camdegrade.profile import CameraProfile

__all__ = ["fit_warnings", "quality_warnings", "still_rising", "validation_quality"]

Log = Callable[[str], None]

#: A network within this much of the baseline's validation PSNR is not warned about (float and crop noise).
BASELINE_TOLERANCE_DB = 0.05
#: A last epoch that adds at least this much validation PSNR (dB) to the best before it says the fit stopped rising
#: too early: more than seed noise moves the best (about ±0.1 dB over a whole fit) spread over its last epoch.
STILL_RISING_DB = 0.05


def validation_quality(
    profile: CameraProfile, scores: dict[str, float], val: PairSet, eight_bit: bool, say: Log
) -> dict[str, Any]:
    """Validation PSNR of identity, the least-squares linear baseline (:mod:`camdegrade.fitting.network.baseline`),
    the trained network's mean (``scores``, :func:`~camdegrade.fitting.steps.network.validation_psnr`; also when the
    profile dropped the network) and the full (stochastic, seeded) profile against the captures, and how close the
    sampled profile looks to the captures (``fidelity``, :func:`_fidelity`)."""
    sampled = profile.simulate(val.cleans(), seed=0, stream="quality")
    full = [psnr(sim, captured) for (_, captured), sim in zip(val.unit_pairs(), sampled, strict=True)]
    return {
        "validation_pairs": len(val),
        "identity_psnr_db": round(scores["identity"], 3),
        "baseline_psnr_db": round(scores["baseline"], 3),
        "network_psnr_db": round(scores["network"], 3),
        "profile_psnr_db": round(sum(full) / len(full), 3),
        "fidelity": _fidelity(as_stored(sampled, eight_bit), val, say),
    }


def _fidelity(sampled: Sequence[torch.Tensor], val: PairSet, say: Log) -> dict[str, Any]:
    """How close the sampled profile (rounded as the captures are stored) looks to the validation captures: grid
    ratio, band log2 power ratios, flat noise and banding ratios (:mod:`camdegrade.measures.fidelity`; ``None``
    where not measurable), and the accuracy of a critic that tells them apart with the clean source beside the
    image (``critic_paired``) and from the image alone (``critic_image_only``, what a model trained on the
    simulation sees): :func:`~camdegrade.measures.critic.repeated_critic_test` with :data:`FIT_CRITIC_SEEDS`
    seeds, ``None`` with fewer than :data:`MIN_CRITIC_SCENES` validation scenes."""
    cleans, captures = zip(*val.unit_pairs(), strict=True)
    report = measure_fidelity(list(sampled), list(captures), list(cleans)).to_dict(digits=3)
    report.pop("psnr")  # profile_psnr_db already
    scenes = len(set(val.scenes))
    for key, image_only in (("critic_paired", False), ("critic_image_only", True)):
        report[key] = None
        if scenes < MIN_CRITIC_SCENES:
            continue
        pairs = (list(cleans), list(captures), list(sampled))
        result = repeated_critic_test(pairs, val.scenes, FIT_CRITIC_SEEDS, image_only=image_only)
        report[key] = result.to_dict()
        say(f"fidelity: {result.describe()} ({'image only' if image_only else 'paired'}, {result.seconds:.1f} s)")
    if scenes < MIN_CRITIC_SCENES:
        say(f"fidelity: no critic ({scenes} validation scene(s); it needs {MIN_CRITIC_SCENES}, half to train it)")
    return report


def fit_warnings(quality: dict[str, Any], history: Sequence[EpochResult], config: FitConfig, kept: bool) -> list[str]:
    """What the validation scores warn about. A dropped network is not warned about (the profile does not hold it),
    unless the captures are the clean images themselves, which is the user's mistake to hear about."""
    identical = not math.isfinite(quality.get("identity_psnr_db", 0.0))
    return quality_warnings(quality) + still_rising(history, config) if kept or identical else []


def quality_warnings(quality: dict[str, Any]) -> list[str]:
    """What a fit's validation scores (:func:`validation_quality`'s) say is wrong: a network that does worse than
    passing the clean image through unchanged (too few epochs, too few pairs, or pairs that show no difference), or
    worse than the least-squares linear baseline (:mod:`camdegrade.fitting.network.baseline`: a simple answer it
    should beat)."""
    network, identity = quality.get("network_psnr_db"), quality.get("identity_psnr_db")
    baseline = quality.get("baseline_psnr_db")
    if network is not None and identity is not None and network < identity:
        return [
            f"the fitted network is worse than the identity on the validation pairs ({_db(network)} vs "
            f"{_db(identity)} for the clean images unchanged): fit longer (--epochs), on more pairs, or check that "
            "the captures differ from the clean images"
        ]
    if network is not None and baseline is not None and network < baseline - BASELINE_TOLERANCE_DB:
        return [
            f"the fitted network is worse than a linear colour filter fitted by least squares on the same pairs "
            f"({_db(network)} vs {_db(baseline)} on the validation pairs): fit longer (--epochs), or use "
            "--arch local_affine, which starts from that filter"
        ]
    return []


def still_rising(history: Sequence[EpochResult], config: FitConfig) -> list[str]:
    """A warning when the fit ran out of epochs while its validation PSNR was still rising: the last epoch was the
    best and beat the best before it by :data:`STILL_RISING_DB` or more."""
    scores = [result.val_psnr for result in history if math.isfinite(result.val_psnr)]
    if len(scores) < 2 or len(history) < config.epochs or not history[-1].is_best:
        return []
    gain = scores[-1] - max(scores[:-1])
    if gain < STILL_RISING_DB:
        return []
    return [
        f"the validation PSNR was still rising at the last epoch (+{gain:.2f} dB over the best before it): the fit "
        f"may stop short; fit longer (--epochs {2 * config.epochs})"
    ]


def _db(value: float) -> str:
    return f"{value:.2f} dB" if math.isfinite(value) else f"{value} dB"
