"""The colour filter array stage of a paired fit: proposed only where the captures hold a Bayer mosaic's 2×2 phase and
the clean images do not, kept only where it brings the simulation's phase to the captures' on the validation pairs.

The trace (:func:`mosaic_trace`): a demosaic keeps each colour where the sensor sampled it and interpolates it
elsewhere, so red less green and blue less green are nearly the mean of their neighbours where red (blue) was not
sampled, and the noise drawn per site before the demosaic is averaged there too; red and blue are sampled at different
phases (:func:`~camdegrade.functional.sensor.cfa.interpolation_phases`,
:func:`~camdegrade.functional.sensor.cfa.colour_phase_share`), where a resampler, a JPEG grid or a readout pattern
leaves one phase pattern in every channel. It reads each image alone, so the captures and the clean images are read
alike: clean images with a mosaic of their own get no second one. (The captures' error to the profile's output, the
pairs' phase statistic :func:`~camdegrade.functional.sensor.cfa.phase_error`, mixes the two: the interpolation error
lowers the error at the sampled sites, the per-site noise raises it, and on a fitted phone they cancel to 0.95.)

The layout is the one the validation captures show; the amount is fitted on the training pairs by the same trace (of
:data:`AMOUNTS` and the squared error's amount, the one whose sampled simulation's trace is nearest the captures'); the
stage is kept where it closes at least :data:`MIN_CLOSED` of the validation trace's gap, or leaves less than
:data:`TRACE_TOLERANCE`. It sits last of the sensor's stages, after the noise: each site's noise is interpolated into
its neighbours, as a camera's is; a noise stage fitted before it is refitted before it, through it, where the
flat-noise ratio comes closer to 1.

Not read through a JPEG with 4:2:0 chroma: the codec averages red and blue over each 2×2 tile (a Bayer camera that
writes JPEG 75 reads 0.99, a camera without a mosaic 0.97–1.0: docs/results.md, *A colour filter array among the
default stages*).

References:
    A. C. Popescu, H. Farid, "Exposing digital forgeries in color filter array interpolated images", IEEE Trans.
    Signal Processing 53(10), 2005 (the periodic trace of interpolation).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import torch
from torch import Tensor

from camdegrade.effects import ColorFilterArray, Effect, Noise
from camdegrade.effects.base import evenly_spaced
from camdegrade.fitting.in_chain import CALIBRATION_PAIRS, fit_stage_in_chain
from camdegrade.fitting.steps.base import FitStep, PairedFit, Verdict
from camdegrade.fitting.steps.noise_evidence import as_stored, relative_gain
from camdegrade.functional.analysis.images import flat_mask
from camdegrade.functional.analysis.noise import measure_set
from camdegrade.functional.sensor.cfa import PATTERNS, colour_phase_share, interpolation_phases
from camdegrade.measures.fidelity import noise_ratios
from camdegrade.profile import CameraProfile

__all__ = [
    "AMOUNTS",
    "MAX_TRACE",
    "MIN_CLOSED",
    "TRACE_TOLERANCE",
    "CfaProposal",
    "CfaStage",
    "MosaicReading",
    "mosaic_trace",
    "read_mosaic",
]

#: Proposed where the captures' trace for a layout is at most this and the clean images' is above it (a phone's
#: Hamilton–Adams mosaic 0.4; cameras without one and real pairs 0.95–1.0: docs/results.md).
MAX_TRACE = 0.85
#: Kept where the stage closes at least this share of the validation trace's gap ...
MIN_CLOSED = 0.5
#: ... or leaves less than this of it.
TRACE_TOLERANCE = 0.03
#: The amounts the fit tries besides the squared error's.
AMOUNTS = tuple(step / 8 for step in range(2, 13))
#: At most this many training pairs (evenly spaced) fit the amount.
MAX_READ = 16


@dataclass(frozen=True)
class MosaicReading:
    """What a set of images shows of a mosaic: the layout whose trace is least, every layout's trace in the captures
    (:func:`mosaic_trace`), and the clean images' trace at that layout."""

    pattern: str
    traces: dict[str, float]
    cleans_trace: float

    @property
    def trace(self) -> float:
        return self.traces[self.pattern]

    def proposed(self) -> bool:
        return self.trace <= MAX_TRACE < self.cleans_trace

    def to_dict(self) -> dict[str, Any]:
        return {
            "pattern": self.pattern,
            "captures_trace": round(self.trace, 3),
            "captures_traces": {layout: round(value, 3) for layout, value in self.traces.items()},
            "cleans_trace": round(self.cleans_trace, 3),
        }


def mosaic_trace(images: Sequence[Tensor], pattern: str) -> float:
    """The trace of a mosaic of ``pattern`` in ``images`` (``(3, H, W)`` each) read alone: the reciprocal of
    :func:`~camdegrade.functional.sensor.cfa.colour_phase_share` of their mean
    :func:`~camdegrade.functional.sensor.cfa.interpolation_phases` (below 1 where they hold one; 1 without; above 1
    for the layout with red and blue swapped)."""
    phases = sum(interpolation_phases(image) for image in images) / len(images)
    return 1.0 / max(colour_phase_share(phases, pattern), 1e-12)


def read_mosaic(cleans: Sequence[Tensor], captures: Sequence[Tensor]) -> MosaicReading:
    """The :class:`MosaicReading` of ``captures`` and their clean images."""
    traces = {pattern: mosaic_trace(captures, pattern) for pattern in PATTERNS}
    pattern = min(PATTERNS, key=traces.__getitem__)
    return MosaicReading(pattern, traces, mosaic_trace(cleans, pattern))


@dataclass(frozen=True)
class CfaProposal:
    """A fitted colour filter array stage and what its proposal read."""

    stage: ColorFilterArray
    note: dict[str, Any]


@dataclass(frozen=True)
class CfaStage(FitStep):
    """The effects step's ``cfa`` stage: proposed by :func:`propose_cfa`, judged by :func:`judge_cfa`; where it is
    kept after a noise stage, that noise is refitted before it (:func:`noise_before_mosaic`)."""

    name: ClassVar[str] = ColorFilterArray.name

    def propose(self, fit: PairedFit) -> CfaProposal | Verdict:
        return propose_cfa(fit)

    def judge(self, fit: PairedFit, proposal: CfaProposal) -> dict[str, Any]:
        kept, record, line = judge_cfa(fit, proposal.stage)
        fit.say(f"effect cfa: {line}")
        record = {**proposal.note, **record}
        if kept is not None:
            fit.keep(True, kept)
            line = noise_before_mosaic(fit)
            if line is not None:
                fit.say(line)
                record["noise_refitted"] = "refitted before" in line
        return record


def propose_cfa(fit: PairedFit) -> CfaProposal | Verdict:
    """The stage where the judged captures show a mosaic and their clean images none (:meth:`MosaicReading.proposed`),
    its amount fitted on the training pairs (:func:`fit_amount`); else the record of why there is none."""
    pairs, label = fit.evidence_pairs
    cleans, captures = (list(side) for side in zip(*pairs, strict=True))
    reading = read_mosaic(cleans, captures)
    note: dict[str, Any] = {**reading.to_dict(), "evidence": label}
    if not reading.proposed():
        reason = (
            f"the clean images hold a {reading.pattern} mosaic as the captures do (trace {reading.cleans_trace:.2f} "
            f"and {reading.trace:.2f})"
            if reading.trace <= MAX_TRACE
            else f"no mosaic in the {label} captures (least trace {reading.trace:.2f}, {reading.pattern})"
        )
        fit.say(f"effect cfa: not fitted: {reason} [evidence: {label}]")
        return Verdict({**note, "kept": False, "reason": reason})
    stage, note["mse_amount"] = fit_amount(fit, reading.pattern)
    return CfaProposal(stage, note)


def fit_amount(fit: PairedFit, pattern: str) -> tuple[ColorFilterArray, float]:
    """The amount of ``pattern``'s demosaic, fitted on (at most :data:`MAX_READ` of) the training pairs: of
    :data:`AMOUNTS` and the squared error's (:meth:`ColorFilterArray.least_squares_amount` on the profile's
    deterministic output), the one whose sampled simulation's :func:`mosaic_trace` is nearest the captures'; and
    the squared error's amount."""
    cleans, captures = (list(side) for side in zip(*evenly_spaced(fit.train_pairs, MAX_READ), strict=True))
    references = fit.profile.simulate(cleans, 0, deterministic=True)
    real = mosaic_trace(captures, pattern)
    nearest, _ = ColorFilterArray.least_squares_amount(list(zip(references, captures, strict=True)), pattern)

    def distance(amount: float) -> float:
        simulated = fit.profile.with_effects(ColorFilterArray(pattern, amount)).simulate(
            cleans, 0, stream="cfa-amount", eight_bit=fit.eight_bit
        )
        return abs(mosaic_trace(simulated, pattern) - real)

    best = min(sorted({*AMOUNTS, round(nearest, 3)}), key=distance)
    return ColorFilterArray(pattern, best), round(nearest, 3)


def judge_cfa(fit: PairedFit, stage: ColorFilterArray) -> tuple[Effect | None, dict[str, Any], str]:
    """``stage`` kept where it brings the sampled simulation's :func:`mosaic_trace` toward the judged captures'
    (:data:`MIN_CLOSED`, :data:`TRACE_TOLERANCE`); the record and log line say by how much, with the share of the
    deterministic output's squared error it removes."""
    pairs, label = fit.evidence_pairs
    cleans, captures = (list(side) for side in zip(*pairs, strict=True))
    real = mosaic_trace(captures, stage.pattern)
    simulated = [
        profile.simulate(cleans, 0, stream="cfa-evidence", eight_bit=fit.eight_bit)
        for profile in (fit.profile, fit.profile.with_effects(stage))
    ]
    without, within = (mosaic_trace(images, stage.pattern) for images in simulated)
    gap, left = real - without, real - within
    kept = abs(left) < TRACE_TOLERANCE or abs(left) <= (1 - MIN_CLOSED) * abs(gap)
    note: dict[str, Any] = {"kept": kept, "amount": round(float(stage.amount), 3), "trace_real": round(real, 3)}
    note |= {"trace_without": round(without, 3), "trace_with": round(within, 3), "evidence": label}
    note["relative_mse_gain"] = round(relative_gain(fit.profile, stage, cleans, captures), 4)
    if not kept:
        note["reason"] = f"it leaves {abs(left):.3f} of the mosaic trace's gap of {abs(gap):.3f}"
    line = (
        f"{stage.pattern} at {float(stage.amount):.3f}: mosaic trace {real:.3f} in the captures, {without:.3f} "
        f"simulated without, {within:.3f} with; relative MSE gain {note['relative_mse_gain']:.2%} on {len(pairs)} "
        f"{label} pair(s) -> {'kept' if kept else 'dropped'}"
    )
    return (stage if kept else None), note, line


def before_mosaic(profile: CameraProfile, noise: Effect) -> CameraProfile:
    """``profile`` with ``noise`` in place of its noise stage, just before its colour filter array: the sensor's
    noise is drawn per site and interpolated by the demosaic."""
    chain = [effect for effect in profile.effects if not isinstance(effect, Noise)]
    index = next(i for i, effect in enumerate(chain) if isinstance(effect, ColorFilterArray))
    return profile.with_chain([*chain[:index], noise, *chain[index:]])


def flat_noise_ratio(profile: CameraProfile, pairs: Sequence[tuple[Tensor, Tensor]], eight_bit: bool) -> float | None:
    """The flat-pixel noise std of ``profile``'s sampled simulation over the captures' (``None``: too few flat
    pixels)."""
    cleans, captures = (list(side) for side in zip(*pairs, strict=True))
    masks = [flat_mask(clean) for clean in cleans]
    simulated = as_stored(profile.simulate(cleans, 0, stream="cfa-noise"), eight_bit)
    return noise_ratios(measure_set(simulated, cleans, masks), measure_set(captures, cleans, masks))[0]


def noise_before_mosaic(fit: PairedFit) -> str | None:
    """With a colour filter array just kept after the profile's noise stage: that noise refitted before it, through
    the demosaic (which averages the noise of the interpolated sites), in its place where the judged pairs'
    flat-noise ratio comes closer to 1; the log line, or ``None`` without a noise stage."""
    if not any(isinstance(effect, Noise) for effect in fit.profile.effects):
        return None
    cleans = [clean for clean, _ in fit.train_pairs]
    captured = [target for _, target in fit.train_pairs]
    with torch.no_grad():
        refit = fit_stage_in_chain(
            fit.profile, Noise, cleans, captured, calibration_pairs=CALIBRATION_PAIRS, insert=before_mosaic
        )
    pairs, label = fit.evidence_pairs
    refitted = before_mosaic(fit.profile, refit)
    ratios = [flat_noise_ratio(profile, pairs, fit.eight_bit) for profile in (fit.profile, refitted)]
    if None in ratios:
        return f"effect noise: not refitted before the cfa stage (too few flat {label} pixels)"
    closer = abs(math.log(ratios[1])) < abs(math.log(ratios[0]))
    if closer:
        fit.profile = refitted
    verdict = "refitted before the cfa stage" if closer else "kept as fitted before the cfa stage was added"
    return f"effect noise: {verdict}: flat-noise ratio {ratios[0]:.2f} as fitted, {ratios[1]:.2f} refitted [{label}]"
