"""A fit's noise-reduction stage: the faint fine detail that the camera's ISP removes and a least-squares profile
passes through from the clean image.

A phone cores its output: faint detail (grain, fine low-contrast texture) is smoothed away and strong edges are
kept. A profile's network is close to linear, so the faint detail of the clean image reaches its output, and a
critic that sees the image alone finds it at once (City100: coring the profile's output lowers the image-only
critic from 0.86 to 0.77, while coring the captures leaves it at chance, 0.51; docs/results.md).

The stage is chosen by the distribution of detail amplitudes, not by least squares: least squares prefers the
conditional mean, and on City100 it picks the largest threshold there is (a blur that halves the mid-band power).
For every candidate (sigma × threshold) the sampled profile's output, with the stage last and rounded to 8 bits,
is compared with the captures by the 1-Wasserstein distance between their distributions of luma detail amplitude
(``|Y − G_s ⊛ Y|`` in 8-bit levels) at the scales :data:`MEASURE_SIGMAS`, summed; the best candidate is kept only
where the validation pairs confirm it (:func:`judge_denoise`).

References:
    J. P. Rossi, "Digital techniques for reducing television noise", SMPTE Journal 87(3), 1978 (coring);
    Y. Blau, T. Michaeli, "The Perception-Distortion Tradeoff", CVPR 2018 (why least squares smooths).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar

import torch
from torch import Tensor

from camdegrade._support.seeds import derived_generator
from camdegrade.effects import Denoise
from camdegrade.fitting.steps.base import FitStep, PairedFit, Verdict
from camdegrade.fitting.steps.texture import band_errors, radial_powers
from camdegrade.functional import blur_planes
from camdegrade.functional.analysis.images import luma
from camdegrade.functional.isp.sharpen import denoised_with_detail, image_detail
from camdegrade.measures.metrics import psnr
from camdegrade.profile import CameraProfile

__all__ = [
    "DENOISE_PAIRS",
    "MAX_BAND_RISE_LOG2",
    "MAX_PSNR_LOSS_DB",
    "MEASURE_SIGMAS",
    "MIN_DISTANCE_DROP",
    "SAMPLES_PER_FRAME",
    "SIGMAS",
    "THRESHOLD_LEVELS",
    "DenoiseMatch",
    "amplitude_distance",
    "detail_amplitudes",
    "eight_bit",
    "judge_denoise",
]

#: Candidate sigmas (pixels) and thresholds (8-bit levels) of the stage.
SIGMAS = (0.7, 1.0, 1.5)
THRESHOLD_LEVELS = (1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0)
#: The detail amplitude is measured at these Gaussian scales (pixels), the finest a critic of 32² patches sees.
MEASURE_SIGMAS = (0.7, 1.0, 1.5)
#: Pixels drawn from each frame for the amplitude distributions (seeded).
SAMPLES_PER_FRAME = 20_000
#: Kept when the validation pairs' amplitude distance falls by at least this share ...
MIN_DISTANCE_DROP = 0.25
#: ... their RMS band error (log2) rises by at most this much ...
MAX_BAND_RISE_LOG2 = 0.1
#: ... and the deterministic output's validation PSNR falls by at most this much (dB).
MAX_PSNR_LOSS_DB = 0.5
#: At most this many training pairs choose it, and as many validation pairs judge it.
DENOISE_PAIRS = 8


def detail_amplitudes(images: Sequence[Tensor], seed: int = 0) -> Tensor:
    """``(len(MEASURE_SIGMAS), N)``: sorted luma detail amplitudes ``|Y − G_s ⊛ Y|`` (8-bit levels) at each scale of
    :data:`MEASURE_SIGMAS`, :data:`SAMPLES_PER_FRAME` pixels drawn from each frame (the same for the same sizes and
    seed)."""
    generator = derived_generator(seed, "detail-amplitudes")
    per_scale: list[list[Tensor]] = [[] for _ in MEASURE_SIGMAS]
    for image in images:
        gray = luma(eight_bit(image))[None]
        where = torch.randint(0, gray.numel(), (SAMPLES_PER_FRAME,), generator=generator)
        for column, sigma in zip(per_scale, MEASURE_SIGMAS, strict=True):
            column.append((gray - blur_planes(gray, sigma)).abs().flatten()[where] * 255.0)
    return torch.stack([torch.cat(column).sort().values for column in per_scale])


def amplitude_distance(sim: Tensor, real: Tensor) -> float:
    """The 1-Wasserstein distance (levels) between two :func:`detail_amplitudes`, summed over the scales."""
    return float((sim - real).abs().mean(-1).sum())


def eight_bit(image: Tensor) -> Tensor:
    return (image.clamp(0, 1) * 255).round() / 255


@dataclass(frozen=True)
class DenoiseMatch(FitStep):
    """The denoise step: a :class:`~camdegrade.effects.Denoise` stage last (after any sharpening: it removes the
    faint detail that the network and the sharpening pass), the candidate whose sampled output's detail amplitudes
    come closest to the training captures', kept where the validation pairs confirm it (:func:`judge_denoise`);
    recorded in ``fitted['denoise']``."""

    name: ClassVar[str] = "denoise"
    needs_network: ClassVar[bool] = True

    def propose(self, fit: PairedFit) -> tuple[Denoise, dict] | Verdict:
        profile, seed, say = fit.profile, fit.seed, fit.say
        if any(isinstance(effect, Denoise) for effect in profile.effects):
            say("denoise: the profile already has a denoise stage; not fitted")
            return Verdict({"kept": False, "reason": "the profile already has a denoise stage"})
        pairs = list(fit.train_pairs)[:DENOISE_PAIRS]
        sampled = profile.simulate([clean for clean, _ in pairs], seed=seed, stream="denoise")
        real = detail_amplitudes([captured for _, captured in pairs], seed)
        distance, sigma, level = _best_candidate(sampled, real, seed)
        before = amplitude_distance(detail_amplitudes(sampled, seed), real)
        note = {
            "sigma": sigma,
            "threshold_levels": level,
            "train_distance_before": before,
            "train_distance_after": distance,
        }
        if distance >= before:
            shown = f"{before:.3f} levels"
            say(f"denoise: no candidate brings the faint detail closer to the captures' ({shown}) -> dropped")
            reason = "no candidate lowers the detail-amplitude distance"
            return Verdict({"kept": False, "reason": reason, **_rounded(note)})
        return Denoise(sigma, level / 255), note

    def judge(self, fit: PairedFit, proposal: tuple[Denoise, dict]) -> dict:
        stage, fitted = proposal
        judged = judge_denoise(fit.profile, stage, fit.judge_pairs(DENOISE_PAIRS), fit.seed)
        fit.say(
            f"denoise: sigma {fitted['sigma']}, threshold {fitted['threshold_levels']} levels -> "
            f"{'kept' if judged['kept'] else 'dropped'} (validation detail-amplitude distance "
            f"{judged['val_distance_before']:.3f} -> {judged['val_distance_after']:.3f} levels, band error "
            f"{judged['val_band_error_before']:.2f} -> {judged['val_band_error_after']:.2f} log2, PSNR "
            f"{judged['val_psnr_before']:.2f} -> {judged['val_psnr_after']:.2f} dB)"
        )
        fit.keep(judged["kept"], stage)
        return _rounded({**fitted, **judged})


def _best_candidate(sampled: Sequence[Tensor], real: Tensor, seed: int) -> tuple[float, float, float]:
    """``(distance, sigma, threshold in levels)`` of the candidate whose output on ``sampled`` comes closest to the
    captures' amplitudes ``real`` (each sigma's detail taken once for all its thresholds: the same outputs)."""
    scored = []
    for sigma in SIGMAS:
        details = [image_detail(image, sigma) for image in sampled]
        for level in THRESHOLD_LEVELS:
            outputs = [denoised_with_detail(s, d, level / 255) for s, d in zip(sampled, details, strict=True)]
            scored.append((amplitude_distance(detail_amplitudes(outputs, seed), real), sigma, level))
    return min(scored)


def _rounded(note: dict) -> dict:
    return {key: round(value, 4) if isinstance(value, float) else value for key, value in note.items()}


def judge_denoise(profile: CameraProfile, stage: Denoise, pairs: Sequence[tuple[Tensor, Tensor]], seed: int) -> dict:
    """The evidence of ``pairs`` (the validation pairs) for adding ``stage`` to ``profile``: kept when the sampled
    output's amplitude distance falls by :data:`MIN_DISTANCE_DROP`, its RMS band error rises by at most
    :data:`MAX_BAND_RISE_LOG2` and the deterministic output's PSNR falls by at most :data:`MAX_PSNR_LOSS_DB`."""
    cleans = [clean for clean, _ in pairs]
    captures = [captured for _, captured in pairs]
    real_amplitudes, real_bands = detail_amplitudes(captures, seed), radial_powers(captures)
    evidence: dict[str, float] = {}
    for when, candidate in (("before", profile), ("after", profile.with_effects(stage))):
        sampled = candidate.simulate(cleans, seed=seed, stream="denoise-check")
        means = candidate.simulate(cleans, seed=seed, deterministic=True)
        evidence[f"val_distance_{when}"] = amplitude_distance(detail_amplitudes(sampled, seed), real_amplitudes)
        errors = band_errors(radial_powers([eight_bit(s) for s in sampled]), real_bands)
        evidence[f"val_band_error_{when}"] = float(errors.pow(2).mean().sqrt())
        evidence[f"val_psnr_{when}"] = sum(psnr(m, c) for m, c in zip(means, captures, strict=True)) / len(pairs)
    kept = (
        evidence["val_distance_after"] <= (1 - MIN_DISTANCE_DROP) * evidence["val_distance_before"]
        and evidence["val_band_error_after"] - evidence["val_band_error_before"] <= MAX_BAND_RISE_LOG2
        and evidence["val_psnr_before"] - evidence["val_psnr_after"] <= MAX_PSNR_LOSS_DB
    )
    return {"kept": kept, **evidence}
