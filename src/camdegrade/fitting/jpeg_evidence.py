"""The JPEG stage of a paired fit: proposed only where the captures hold JPEG's fingerprint, kept only where it
brings the simulation's block edges to the captures' on the validation pairs.

The fingerprint is the quantisation lattice (:mod:`camdegrade.measures.traces.quantisation`): a decoded JPEG's 8×8
blocks keep their DCT coefficients on multiples of the table's steps, which no resize, blur, noise or tone curve
makes (0 of 20 resampled or upscaled photos, every JPEG of quality 30–95: docs/results.md, *JPEG from its
quantisation lattice*). A camera without a codec, or clean images compressed as much as the captures, gives no
stage, and the stage is not fitted at all (the default fit pays the lattice reading only: about 0.1 s an image).
What the codec does to the look is its blocks: the gradient energy across the 8×8 block edges
(:func:`block_edge_ratio`). The quality is fitted on the training pairs by that statistic (:func:`fit_quality`),
and the stage is kept where it moves the sampled simulation's toward the captures' on the validation pairs: it
closes at least :data:`MIN_CLOSED` of that gap or leaves less than :data:`BLOCK_TOLERANCE` of it.

Where it sits: at the codec's place, last. A codec at the sensor's resolution before the ISP's upscale (its blocks
come out 16 px for a 2× zoom, and the lattice is gone) cannot be placed in the profile: ``resolution`` is one stage
that reduces and enlarges, so a JPEG put before it compresses the full frame and its grid stays 8 px. Such captures
get no stage; the record names the block edges at the sensor's period (:func:`sensor_grid_note`), and the fit warns
where they stand out (:func:`camdegrade.fitting.codec_warning.codec_warnings`).

References:
    Z. Fan, R. L. de Queiroz, "Identification of bitmap compression history: JPEG detection and quantizer
    estimation", IEEE Trans. Image Processing 12(2), 2003.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from fractions import Fraction
from typing import Any, ClassVar

import torch
from torch import Tensor

from camdegrade.effects import JPEG, Effect, Noise, Resolution
from camdegrade.effects.base import evenly_spaced
from camdegrade.fitting.evidence.statistic import judge_by_statistic
from camdegrade.fitting.in_chain import CALIBRATION_PAIRS, fit_stage_in_chain, in_its_place
from camdegrade.fitting.steps.base import FitStep, PairedFit, Verdict, keep_and_refit_noise
from camdegrade.fitting.steps.noise_evidence import noise_evidence
from camdegrade.functional.analysis.images import luma
from camdegrade.measures.traces.quantisation import read_lattice

__all__ = [
    "BLOCK_TOLERANCE",
    "MIN_CLOSED",
    "JpegProposal",
    "JpegStage",
    "block_edge_ratio",
    "fit_quality",
    "judge_jpeg",
    "lattice_counts",
    "noise_through_codec",
    "propose_jpeg",
    "sensor_grid_note",
]

#: The stage is proposed when at least this share of the captures that tell (on the lattice or clearly off it)
#: hold the lattice, and more of them than of the clean images.
MIN_COMPRESSED_SHARE = 0.5
#: At most this many captures are read (evenly spaced); reading costs 40–180 ms an image.
MAX_READ = 16
#: Kept where the stage closes at least this share of the validation block-edge gap (what is left counts, on either
#: side of the captures: a quality 5 off overshoots) ...
MIN_CLOSED = 0.5
#: ... or leaves it below this (relative gradient energy).
BLOCK_TOLERANCE = 0.03
#: The qualities the fit tries besides the squared error's.
QUALITIES = tuple(range(10, 100, 5))
#: A JPEG block is this many pixels on a side at the resolution it was compressed at.
BLOCK = 8


def block_edge_ratio(images: Sequence[Tensor], period: int = BLOCK) -> float:
    """Mean over ``images`` (``(3, H, W)`` in [0, 1]) and both directions of the luma gradient energy across the
    edges of a ``period``-pixel grid from the origin (between pixels ``period - 1`` and ``period``), relative to
    its mean over the grid's phases of the same parity: a 2× upscale alternates the gradient energy between odd and
    even phases, and the edge lies on an odd one. 1: no grid; a JPEG's blocks lift it (quality 75: about 1.3)."""
    same = [phase for phase in range(period) if phase % 2 == (period - 1) % 2]
    ratios = []
    for image in images:
        gray = luma(image)
        for grad in ((gray[:, 1:] - gray[:, :-1]).abs(), (gray[1:, :] - gray[:-1, :]).abs().T):
            length = grad.shape[1] // period * period
            if length < period:
                continue
            profile = grad[:, :length].mean(0).reshape(-1, period).mean(0)
            mean = float(profile[same].mean())
            if mean > 0:
                ratios.append(float(profile[period - 1]) / mean)
    return sum(ratios) / len(ratios) if ratios else float("nan")


def lattice_counts(images: Sequence[Tensor]) -> tuple[int, int]:
    """``(on the lattice, telling either way)`` of at most :data:`MAX_READ` of ``images``, evenly spaced."""
    readings = [read_lattice(image) for image in evenly_spaced(list(images), MAX_READ)]
    return sum(reading.compressed for reading in readings), sum(reading.determined for reading in readings)


@dataclass(frozen=True)
class JpegProposal:
    """A fitted JPEG stage and what its proposal read (the lattice counts)."""

    stage: JPEG
    note: dict[str, Any]


@dataclass(frozen=True)
class JpegStage(FitStep):
    """The effects step's ``jpeg`` stage: :func:`propose_jpeg`, then :func:`judge_jpeg`; where it is kept after a
    noise stage, that noise is refitted through it (:func:`noise_through_codec`)."""

    name: ClassVar[str] = "jpeg"

    def propose(self, fit: PairedFit) -> JpegProposal | Verdict:
        return propose_jpeg(fit)

    def judge(self, fit: PairedFit, proposal: JpegProposal) -> dict[str, Any]:
        judged = judge_jpeg(fit, proposal.stage)
        return keep_and_refit_noise(fit, self.name, judged, proposal.note, noise_through_codec, "refitted through")


def propose_jpeg(fit: PairedFit) -> JpegProposal | Verdict:
    """The JPEG stage where the judged captures hold the lattice (:data:`MIN_COMPRESSED_SHARE`) more often than the
    clean images, its quality fitted on the training pairs; else the record of why there is none (not fitted)."""
    pairs, label = fit.evidence_pairs
    on, telling = lattice_counts([captured for _, captured in pairs])
    clean_on, _ = lattice_counts([clean for clean, _ in pairs])
    note: dict[str, Any] = {"captures_on_lattice": on, "captures_telling": telling, "cleans_on_lattice": clean_on}
    if telling == 0 or on < MIN_COMPRESSED_SHARE * telling or on <= clean_on:
        reason = (
            f"the clean images hold the lattice as often ({clean_on}) as the captures ({on}): compressed again"
            if on and on <= clean_on
            else f"{on} of {telling} {label} captures hold JPEG's quantisation lattice (clean images: {clean_on})"
        )
        note |= {"kept": False, "reason": reason, "evidence": label, **sensor_grid_note(fit, pairs)}
        fit.say(f"effect jpeg: not fitted: {reason} [evidence: {label}]")
        return Verdict(note)
    stage, note["mse_quality"] = fit_quality(fit)
    return JpegProposal(stage, note)


def fit_quality(fit: PairedFit) -> tuple[JPEG, int]:
    """The quality, fitted on (at most :data:`MAX_READ` of) the training pairs: of :data:`QUALITIES` and the one
    nearest in squared error (:meth:`~camdegrade.effects.JPEG.fit`, on the profile's deterministic output), the one
    whose sampled simulation's :func:`block_edge_ratio` is nearest the captures'; and the squared error's quality.
    The squared error alone chooses too high a quality: the profile's output is smoother than the camera's before
    its codec (a network trained on the captures has learned part of the codec's loss), and noiseless."""
    pairs = evenly_spaced(fit.train_pairs, MAX_READ)
    cleans, captures = (list(side) for side in zip(*pairs, strict=True))
    nearest = JPEG.fit(fit.profile.simulate(cleans, 0, deterministic=True), captures)
    real = block_edge_ratio(captures)

    def distance(quality: int) -> float:
        images = fit.profile.with_effects(JPEG(quality)).simulate(cleans, 0, stream="jpeg-quality", eight_bit=True)
        return abs(block_edge_ratio(images) - real)

    best = min(sorted({*QUALITIES, int(nearest.quality)}), key=distance)
    return JPEG(best), int(nearest.quality)


def sensor_grid_note(fit: PairedFit, pairs: Sequence[tuple[Tensor, Tensor]]) -> dict[str, Any]:
    """Where the profile enlarges a sensor of ``scale`` < 1 by an integer factor: the block-edge ratio at the
    sensor's block period (``8 / scale`` px) of the captures and of the sampled profile (a codec before the ISP's
    upscale, which the profile cannot place); ``{}`` otherwise."""
    sensors = [effect for effect in fit.profile.effects if isinstance(effect, Resolution)]
    if not sensors:
        return {}
    period = Fraction(BLOCK) / Fraction(float(sensors[0].scale)).limit_denominator(64)
    if period.denominator != 1 or period <= BLOCK:
        return {}
    cleans, captures = zip(*pairs, strict=True)
    simulated = fit.profile.simulate(list(cleans), 0, stream="jpeg-evidence", eight_bit=True)
    real, sim = block_edge_ratio(captures, int(period)), block_edge_ratio(simulated, int(period))
    return {"sensor_period": int(period), "sensor_grid_real": round(real, 3), "sensor_grid_sim": round(sim, 3)}


def judge_jpeg(fit: PairedFit, stage: JPEG) -> tuple[Effect | None, dict[str, Any], str]:
    """``stage`` kept where it brings the sampled simulation's :func:`block_edge_ratio` toward the judged
    captures' (:data:`MIN_CLOSED`, :data:`BLOCK_TOLERANCE`); the record and log line say by how much, with the
    share of the deterministic output's squared error it removes."""
    judged = judge_by_statistic(
        fit,
        stage,
        block_edge_ratio,
        stream="jpeg-evidence",
        eight_bit=True,
        tolerance=BLOCK_TOLERANCE,
        share=MIN_CLOSED,
    )
    note: dict[str, Any] = {"kept": judged.kept, "quality": int(stage.quality)}
    note |= judged.record("block_edges", "the block-edge gap")
    line = (
        f"quality {int(stage.quality)}: 8×8 block edges {judged.real:.3f}× the mean in the captures, "
        f"{judged.without:.3f}× simulated without, {judged.within:.3f}× with; {judged.line_end()}"
    )
    return (stage if judged.kept else None), note, line


def noise_through_codec(fit: PairedFit) -> str | None:
    """With a JPEG stage just kept after the profile's noise stage: that noise refitted through the codec (the codec
    smooths it, and it was calibrated without one) at the place it holds (after a resampler, where an earlier step put
    it there: :func:`~camdegrade.fitting.in_chain.in_its_place`), in place of it where the judged pairs' flat-noise
    ratio comes closer to 1 with it (:func:`~camdegrade.fitting.steps.noise_evidence.noise_evidence`); the log line,
    or ``None`` without a noise stage."""
    old = next((effect for effect in fit.profile.effects if isinstance(effect, Noise)), None)
    if old is None:
        return None
    cleans = [clean for clean, _ in fit.train_pairs]
    captured = [target for _, target in fit.train_pairs]
    with torch.no_grad():
        refit = fit_stage_in_chain(
            fit.profile, Noise, cleans, captured, calibration_pairs=CALIBRATION_PAIRS, insert=in_its_place
        )
    pairs, label = fit.evidence_pairs
    judged = [list(side) for side in zip(*pairs, strict=True)]
    evidence = [
        noise_evidence(fit.profile, stage, *judged, eight_bit=fit.eight_bit, insert=in_its_place)[1]
        for stage in (old, refit)
    ]
    ratios = [found.noise_ratio_with for found in evidence]
    if None in ratios:
        return f"effect noise: not refitted through the jpeg stage (too few flat {label} pixels)"
    closer = abs(math.log(ratios[1])) < abs(math.log(ratios[0]))
    if closer:
        fit.profile = in_its_place(fit.profile, refit)
    verdict = "refitted through the jpeg stage" if closer else "kept as fitted before the jpeg stage"
    return f"effect noise: {verdict}: flat-noise ratio {ratios[0]:.2f} as fitted, {ratios[1]:.2f} refitted [{label}]"
