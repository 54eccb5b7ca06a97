"""A fit's displacement step: a :class:`~camdegrade.effects.Jitter` stage where the captures' detail is less
coherent with the clean image than the profile's, by the amount a random displacement explains.

Why: a network trained for the conditional mean averages the captures' displacement into a blur, and the texture
and response steps then give the sample the captures' power with the clean image's detail in place. On City100 the
built-in's sample held 0.81 of the clean image's detail at 0.16–0.25 cycles/pixel where the captures hold 0.46; a
restorer trained on it learned to amplify detail the camera does not keep and made the real captures worse
(docs/results.md, *Restoration transfer*).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar

import torch
from torch import Tensor

from camdegrade.effects import Jitter
from camdegrade.fitting.evidence.mosaic_guard import critic_guard, guard_line
from camdegrade.fitting.steps.base import FitStep, PairedFit, Verdict
from camdegrade.fitting.steps.denoise import eight_bit
from camdegrade.fitting.steps.texture import MAX_PSNR_LOSS_DB
from camdegrade.functional.analysis.coherence import DETAIL_ABOVE, bin_centres, coherence, displacement_sigma
from camdegrade.measures.metrics import psnr
from camdegrade.profile import CameraProfile

__all__ = ["JITTER_PAIRS", "MIN_SIGMA", "JitterMatch", "judge_jitter", "read_sigma", "with_jitter"]

#: At most this many training pairs read the displacement, and as many validation pairs judge it.
JITTER_PAIRS = 16
#: A displacement below this (pixels per axis) is not proposed: it moves the coherence by under 2 % below
#: 0.25 cycles/pixel.
MIN_SIGMA = 0.1
#: The judge compares coherences over the bins where the captures' is at least this: below it both are noise.
MEASURABLE = 0.1
#: Kept where the stage lowers the coherence distance to the captures by at least this: more than two sets of 8
#: scenes of one camera differ by (City100: 0.012–0.046 over six random draws, docs/results.md).
MIN_GAIN = 0.05

Pairs = Sequence[tuple[Tensor, Tensor]]


def read_sigma(profile: CameraProfile, pairs: Pairs, seed: int) -> float | None:
    """The displacement (pixels per axis) between the profile's deterministic output and the captures of
    ``pairs``, beyond the incoherence its own sample already has (its noise, its texture)."""
    cleans = [clean for clean, _ in pairs]
    means = profile.simulate(cleans, seed, deterministic=True)
    samples = [eight_bit(image) for image in profile.simulate(cleans, seed, stream="jitter")]
    return displacement_sigma(coherence(means, samples), coherence(means, [captured for _, captured in pairs]))


def with_jitter(profile: CameraProfile, stage: Jitter) -> CameraProfile:
    """``profile`` with ``stage`` first in its chain: the scene is displaced before the lens and the sensor see it,
    and the linear stages after it stay adjacent (a chain composes them into one filter)."""
    return profile.with_chain([stage, *profile.effects])


def _distance(simulated: Tensor, real: Tensor) -> float:
    """RMS difference of two coherence curves over the bins above
    :data:`~camdegrade.functional.analysis.coherence.DETAIL_ABOVE` where ``real`` is measurable."""
    usable = (bin_centres() > DETAIL_ABOVE) & (real >= MEASURABLE)
    return float((simulated - real)[usable].pow(2).mean().sqrt()) if bool(usable.any()) else 0.0


def judge_jitter(profile: CameraProfile, jittered: CameraProfile, pairs: Pairs, seed: int) -> dict:
    """The evidence of ``pairs`` (the validation pairs) for ``jittered``, ``profile`` with a jitter stage
    (:func:`with_jitter`): the sample's coherence with the clean image per radial bin against the captures', without
    and with it (kept where the RMS distance falls by
    :data:`MIN_GAIN`), and the deterministic output's PSNR (at most
    :data:`~camdegrade.fitting.steps.texture.MAX_PSNR_LOSS_DB` lost)."""
    cleans = [clean for clean, _ in pairs]
    captures = [captured for _, captured in pairs]
    real = coherence(cleans, captures)
    evidence: dict[str, float] = {}
    for when, candidate in (("before", profile), ("after", jittered)):
        samples = [eight_bit(image) for image in candidate.simulate(cleans, seed, stream="jitter-check")]
        means = candidate.simulate(cleans, seed, deterministic=True)
        evidence[f"val_coherence_distance_{when}"] = _distance(coherence(cleans, samples), real)
        evidence[f"val_psnr_{when}"] = sum(psnr(m, c) for m, c in zip(means, captures, strict=True)) / len(pairs)
    before, after = evidence["val_coherence_distance_before"], evidence["val_coherence_distance_after"]
    kept = before - after >= MIN_GAIN and evidence["val_psnr_before"] - evidence["val_psnr_after"] <= MAX_PSNR_LOSS_DB
    return {"kept": kept, **evidence}


@dataclass(frozen=True)
class JitterMatch(FitStep):
    """The jitter step: a :class:`~camdegrade.effects.Jitter` of the displacement read on the training pairs
    (:func:`read_sigma`), kept where the validation pairs confirm it (:func:`judge_jitter`) and a fresh image-only
    critic does not find the profile easier to tell from the captures with it (the cfa stage's guard,
    :func:`~camdegrade.fitting.evidence.mosaic_guard.critic_guard`: a coherence loss read as a shift may be the
    camera's texture); recorded in ``fitted['jitter']``."""

    name: ClassVar[str] = "jitter"
    needs_network: ClassVar[bool] = True

    def propose(self, fit: PairedFit) -> Jitter | Verdict:
        if any(isinstance(effect, Jitter) for effect in fit.profile.effects):
            return Verdict({"kept": False, "reason": "the profile already has a jitter stage"})
        with torch.no_grad():
            sigma = read_sigma(fit.profile, list(fit.train_pairs)[:JITTER_PAIRS], fit.seed)
        if sigma is None or sigma < MIN_SIGMA:
            why = (
                "displacement not readable (fewer than 3 frequencies coherent enough)"
                if sigma is None
                else f"displacement {sigma:.2f} px, under {MIN_SIGMA} px"
            )
            fit.say(f"jitter: {why}: not fitted")
            return Verdict({"kept": False, "sigma": sigma, "reason": why})
        return Jitter(min(sigma, Jitter.MAX_SIGMA))

    def judge(self, fit: PairedFit, stage: Jitter) -> dict:
        jittered = with_jitter(fit.profile, stage)
        with torch.no_grad():
            evidence = judge_jitter(fit.profile, jittered, fit.judge_pairs(JITTER_PAIRS), fit.seed)
        note = {"sigma": round(float(stage.sigma), 4), "scale": float(stage.scale)}
        note.update({key: round(value, 4) if isinstance(value, float) else value for key, value in evidence.items()})
        line = (
            f"jitter: {note['sigma']:.2f} px RMS per axis (validation coherence distance "
            f"{note['val_coherence_distance_before']:.3f} -> {note['val_coherence_distance_after']:.3f}, PSNR "
            f"{note['val_psnr_before']:.2f} -> {note['val_psnr_after']:.2f} dB)"
        )
        if note["kept"]:  # the coherence says a displacement; a fresh critic must not find the images easier to tell
            note["critic"] = critic_guard(fit, fit.profile, jittered)
            note["kept"] = note["critic"]["not_easier"]
            line += f"; {guard_line(note['critic'])}"
        fit.say(f"{line} -> {'kept' if note['kept'] else 'dropped'}")
        if note["kept"]:
            fit.profile = jittered
        return note
