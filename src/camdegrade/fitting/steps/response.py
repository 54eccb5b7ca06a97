"""A fit's last stage: the frequency response that gives the sampled profile the captures' luma spectrum.

The texture stages (:mod:`camdegrade.fitting.steps.texture`: one blur, one unsharp mask) and the noise reduction
(:mod:`camdegrade.fitting.steps.denoise`) leave the sampled profile's spectrum off the captures' where no Gaussian
family bends: on City100 the built-in stayed −0.50 and −1.14 log2 short at 0.16–0.25 and 0.25–0.35 cycles/pixel,
because the captures' detail there is not where the clean image's is (coherence 0.06 at 0.23–0.25) and least
squares shrinks it. A :class:`~camdegrade.effects.FrequencyResponse` fitted to the captures' power per frequency
cell (a distribution, not a regression) restores it; it is kept only where the validation pairs confirm it
(:func:`judge_response`).

References:
    Y. Blau, T. Michaeli, "The Perception-Distortion Tradeoff", CVPR 2018 (why matching the distribution costs
    distortion, and why least squares smooths).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar

from torch import Tensor

from camdegrade.effects import FrequencyResponse
from camdegrade.fitting.steps.base import FitStep, PairedFit, Verdict
from camdegrade.fitting.steps.denoise import eight_bit
from camdegrade.fitting.steps.texture import MAX_PSNR_LOSS_DB, MIN_BAND_GAIN_LOG2, band_errors, radial_powers
from camdegrade.measures.fidelity import grid_rms
from camdegrade.measures.metrics import psnr
from camdegrade.profile import CameraProfile

__all__ = ["MAX_GRID_RATIO", "RESPONSE_PAIRS", "ResponseMatch", "judge_response"]

#: At most this many training pairs fit the response, and as many validation pairs judge it (City100: 16 frames
#: of 840×600; each frame's power per cell is a noisy estimate, so a mean over frames needs a dozen or more).
RESPONSE_PAIRS = 16
#: The response is dropped if the sampled output's 4×4 grid (:func:`~camdegrade.measures.fidelity.grid_rms`) on the
#: validation pairs ends above this many times the captures' and above what it was without the response: a gain on
#: the frequencies beside the lattice amplifies a network's fixed pattern (the grid line of the fidelity work).
MAX_GRID_RATIO = 1.5


@dataclass(frozen=True)
class ResponseMatch(FitStep):
    """The response step: a :class:`~camdegrade.effects.FrequencyResponse` last, fitted on the training pairs
    between the profile's sampled output (8-bit, as training sees it) and the captures, kept where the validation
    pairs confirm it (:func:`judge_response`); recorded in ``fitted['response']``."""

    name: ClassVar[str] = "response"
    needs_network: ClassVar[bool] = True

    def propose(self, fit: PairedFit) -> FrequencyResponse | Verdict:
        if any(isinstance(effect, FrequencyResponse) for effect in fit.profile.effects):
            fit.say("response: the profile already has a frequency response; not fitted")
            return Verdict({"kept": False, "reason": "the profile already has a frequency response"})
        pairs = list(fit.train_pairs)[:RESPONSE_PAIRS]
        cleans = [clean for clean, _ in pairs]
        sampled = [eight_bit(image) for image in fit.profile.simulate(cleans, fit.seed, stream="response")]
        return FrequencyResponse.fit(sampled, [captured for _, captured in pairs])

    def judge(self, fit: PairedFit, stage: FrequencyResponse) -> dict:
        evidence = judge_response(fit.profile, stage, fit.judge_pairs(RESPONSE_PAIRS), fit.seed)
        note = {"knots": stage.knots, "magnitude": stage.magnitude(), **evidence}
        note = {key: round(value, 4) if isinstance(value, float) else value for key, value in note.items()}
        fit.say(
            f"response: {stage.knots}x{stage.knots} knots, {note['magnitude']:.2f} log2 RMS -> "
            f"{'kept' if note['kept'] else 'dropped'} (validation band error {note['val_band_error_before']:.2f} -> "
            f"{note['val_band_error_after']:.2f} log2, grid ratio {note['val_grid_before']:.2f} -> "
            f"{note['val_grid_after']:.2f}, PSNR {note['val_psnr_before']:.2f} -> {note['val_psnr_after']:.2f} dB)"
        )
        fit.keep(note["kept"], stage)
        return note


def judge_response(
    profile: CameraProfile, stage: FrequencyResponse, pairs: Sequence[tuple[Tensor, Tensor]], seed: int
) -> dict:
    """The evidence of ``pairs`` (the validation pairs) for adding ``stage`` last: kept when the sampled output's
    RMS band error falls by :data:`~camdegrade.fitting.steps.texture.MIN_BAND_GAIN_LOG2`, its grid ratio stays
    within :data:`MAX_GRID_RATIO` (or no higher than before) and the deterministic output's PSNR falls by at most
    :data:`~camdegrade.fitting.steps.texture.MAX_PSNR_LOSS_DB` (the soft simulated camera's response costs 1.16 dB
    and is dropped; kept, it would take that noiseless camera's flat-noise ratio to 3.7 and its banding ratio to 6.8,
    docs/fitting.md)."""
    cleans = [clean for clean, _ in pairs]
    captures = [captured for _, captured in pairs]
    real_bands = radial_powers(captures)
    real_grid = sum(grid_rms(captured) for captured in captures) / len(captures)
    evidence: dict[str, float] = {}
    for when, candidate in (("before", profile), ("after", profile.with_effects(stage))):
        sampled = [eight_bit(image) for image in candidate.simulate(cleans, seed, stream="response-check")]
        means = candidate.simulate(cleans, seed, deterministic=True)
        evidence[f"val_band_error_{when}"] = float(band_errors(radial_powers(sampled), real_bands).pow(2).mean().sqrt())
        evidence[f"val_grid_{when}"] = sum(grid_rms(image) for image in sampled) / len(sampled) / max(real_grid, 1e-9)
        evidence[f"val_psnr_{when}"] = sum(psnr(m, c) for m, c in zip(means, captures, strict=True)) / len(pairs)
    grid_after = evidence["val_grid_after"]
    kept = (
        evidence["val_band_error_before"] - evidence["val_band_error_after"] >= MIN_BAND_GAIN_LOG2
        and (grid_after <= MAX_GRID_RATIO or grid_after <= evidence["val_grid_before"])
        and evidence["val_psnr_before"] - evidence["val_psnr_after"] <= MAX_PSNR_LOSS_DB
    )
    return {"kept": kept, **evidence}
