"""The colour filter array stage of a paired fit: proposed only where the captures hold a Bayer mosaic's trace and
the clean images do not, kept only where it brings the simulation's trace to the captures' on the validation pairs.

The trace is read in each image alone (:mod:`camdegrade.measures.traces.mosaic`): red and blue less green are smooth
where a layout interpolates them (the colour route), or, behind a JPEG with 4:2:0 chroma, luma is smoothest where the
layout samples blue (the luma route). The captures' error to the profile's output (the
pairs' phase statistic :func:`~camdegrade.functional.sensor.cfa.phase_error`) mixes two opposite traces: the
interpolation lowers the error at the sampled sites, the per-site noise raises it, and on a fitted phone they cancel
(0.95).

The layout is the one the validation captures show; the amount is fitted on the training pairs by the route's trace
(of :data:`AMOUNTS` and the squared error's amount, the one whose sampled simulation's trace is nearest the
captures'), for a bilinear and an edge-directed demosaic, and the one of the two that leaves the smaller squared error
is chosen (:func:`fit_stage`); the stage is kept where it closes at least :data:`MIN_CLOSED` of the validation
trace's gap, or leaves less than :data:`TRACE_TOLERANCE`, and a fresh image-only critic on the validation pairs
finds the simulation with it no easier to tell from the captures
(:func:`~camdegrade.fitting.evidence.mosaic_guard.critic_guard`: a trace matched by a demosaic that is not the
camera's can still be seen). It sits last of the sensor's stages, after the noise: each
site's noise is interpolated into its neighbours, as a camera's is; a noise stage fitted before it is refitted before
it, through it, where the flat-noise ratio comes closer to 1. It is judged after the codec's stage (the effects step
runs it last), so the luma route reads the simulation through the profile's JPEG as the captures were written.
The luma route fits and judges by the whole form of luma's phases (:func:`distance_to`), not by blue's site over
red's alone: on a BGGR camera demosaiced by OpenCV the ratio was matched by a stage that tripled the diagonal
contrast, and the critic saw it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import torch
from torch import Tensor

from camdegrade._support.seeds import derived_generator
from camdegrade.effects import ColorFilterArray, Effect, Noise
from camdegrade.effects.base import evenly_spaced
from camdegrade.fitting.evidence.mosaic_guard import guard_kept
from camdegrade.fitting.evidence.statistic import judge_by_statistic
from camdegrade.fitting.in_chain import CALIBRATION_PAIRS, fit_stage_in_chain
from camdegrade.fitting.steps.base import FitStep, PairedFit, Verdict, keep_and_refit_noise
from camdegrade.fitting.steps.noise_evidence import as_stored
from camdegrade.functional.analysis.images import flat_mask
from camdegrade.functional.analysis.noise import measure_set
from camdegrade.functional.sensor.cfa import DEMOSAICS
from camdegrade.measures.fidelity import noise_ratios
from camdegrade.measures.traces.mosaic import MAX_TRACE, ROUTES, read_mosaic
from camdegrade.measures.traces.mosaic_form import CHECKER_FLOOR, form_vector
from camdegrade.profile import CameraProfile

__all__ = [
    "AMOUNTS",
    "JUDGE_DRAWS",
    "MAX_PROPOSAL",
    "MIN_CLOSED",
    "TRACE_TOLERANCE",
    "CfaProposal",
    "CfaStage",
    "judge_cfa",
    "propose_cfa",
]

#: Kept where the stage closes at least this share of the validation trace's gap ...
MIN_CLOSED = 0.5
#: ... or leaves less than this of it (the colour route's trace) ...
TRACE_TOLERANCE = 0.03
#: ... by route (the luma route's form: what the null leaves of the checker without a pattern).
TOLERANCES = {"colour": TRACE_TOLERANCE, "luma": CHECKER_FLOOR}
#: What each route compares.
READS = {"colour": "colour trace", "luma": "luma form"}
#: The amounts the fit tries besides the squared error's.
AMOUNTS = tuple(step / 8 for step in range(2, 9))
#: At most this many training pairs (evenly spaced) fit the amount.
MAX_READ = 16
#: At most this many training pairs (evenly spaced) are read for the proposal.
MAX_PROPOSAL = 64
#: The judgement reads this many noise draws of the simulation (seeds 0, 1, ...): one draw of 10 pairs moves the luma
#: trace by ±0.02 (docs/results.md, *bayer-jpeg: why its held-out critic reads 0.71*).
JUDGE_DRAWS = 4


@dataclass(frozen=True)
class CfaProposal:
    """A fitted colour filter array stage, the route its trace is read by
    (:data:`~camdegrade.measures.traces.mosaic.ROUTES`) and what its proposal read."""

    stage: ColorFilterArray
    route: str
    note: dict[str, Any]


@dataclass(frozen=True)
class CfaStage(FitStep):
    """The effects step's ``cfa`` stage: proposed by :func:`propose_cfa`, judged by :func:`judge_cfa`; where it is
    kept after a noise stage, that noise is refitted before it (:func:`noise_before_mosaic`), and the profile so
    made is kept where the fresh critic finds it no easier than the one before
    (:func:`~camdegrade.fitting.evidence.mosaic_guard.guard_kept`)."""

    name: ClassVar[str] = ColorFilterArray.name

    def propose(self, fit: PairedFit) -> CfaProposal | Verdict:
        return propose_cfa(fit)

    def judge(self, fit: PairedFit, proposal: CfaProposal) -> dict[str, Any]:
        before, judged = fit.profile, judge_cfa(fit, proposal.stage, proposal.route)
        record = keep_and_refit_noise(fit, self.name, judged, proposal.note, noise_before_mosaic, "refitted before")
        return guard_kept(fit, before, record, "effect cfa: ") if record["kept"] else record


def propose_cfa(fit: PairedFit) -> CfaProposal | Verdict:
    """The stage where the training captures (at most :data:`MAX_PROPOSAL`, evenly spaced) show a mosaic and their
    clean images none (:meth:`~camdegrade.measures.traces.mosaic.MosaicReading.proposed`: read on the training
    pairs, the more of them the narrower the luma route's bound, and judged on the validation pairs), its amount
    fitted on the training pairs (:func:`fit_stage`); else the record of why there is none."""
    pairs, label = evenly_spaced(fit.train_pairs, MAX_PROPOSAL), "training"
    cleans, captures = (list(side) for side in zip(*pairs, strict=True))
    reading = read_mosaic(cleans, captures, derived_generator(fit.seed, "cfa-luma-bootstrap"))
    note: dict[str, Any] = {**reading.to_dict(), "evidence": label}
    if not reading.proposed():
        reason = _unproposed(reading.to_dict(), label)
        fit.say(f"effect cfa: not fitted: {reason} [evidence: {label}]")
        return Verdict({**note, "kept": False, "reason": reason})
    stage, fitted = fit_stage(fit, reading.pattern, reading.route)
    note |= fitted
    return CfaProposal(stage, reading.route, note)


def _unproposed(note: dict[str, Any], label: str) -> str:
    """Why a reading (:meth:`MosaicReading.to_dict`) proposes no stage."""
    pattern, trace, cleans = note["pattern"], note["captures_trace"], note["cleans_trace"]
    if note["route"] == "colour":
        return f"the clean images hold a {pattern} mosaic as the captures do (trace {cleans:.2f} and {trace:.2f})"
    if note["ordered"] and note["cleans_form"]:
        return (
            f"the clean images' luma holds a {pattern} mosaic's form as the captures' does ({cleans:.2f}, {trace:.2f})"
        )
    return (
        f"no mosaic in the {label} captures (least colour trace above {MAX_TRACE}; luma {pattern} {trace:.2f}, form "
        f"{note['form_ratio']:.2f} of the row and column contrast, bound {note['form_bound']:+.3f}, "
        f"{'in' if note['ordered'] else 'not in'} a mosaic's order)"
    )


def fit_stage(fit: PairedFit, pattern: str, route: str) -> tuple[ColorFilterArray, dict[str, Any]]:
    """The stage of ``pattern``, fitted on (at most :data:`MAX_READ` of) the training pairs: for each demosaic of
    :data:`~camdegrade.functional.sensor.cfa.DEMOSAICS`, the amount whose sampled simulation's trace (by ``route``)
    is nearest the captures' (:func:`fit_amount`); of the demosaics whose trace closes at least :data:`MIN_CLOSED`
    of the training trace's gap, the one whose stage leaves the smaller squared error on the profile's deterministic
    output (the error tells which interpolates as the camera did); the one nearest in trace where none does. The note
    gives each demosaic's amount, the trace's distance left, the squared error's amount and relative error gain."""
    cleans, captures = (list(side) for side in zip(*evenly_spaced(fit.train_pairs, MAX_READ), strict=True))
    references = fit.profile.simulate(cleans, 0, deterministic=True)
    pairs = list(zip(references, captures, strict=True))
    before = sum(float((r - c).pow(2).sum()) for r, c in pairs)
    stages, note = {}, {}
    for demosaic in DEMOSAICS:
        nearest, _ = ColorFilterArray.least_squares_amount(pairs, pattern, demosaic)
        start = ColorFilterArray(pattern, min(nearest, 1.0), demosaic)
        stage, left, gap = fit_amount(fit, cleans, captures, start, route)
        with torch.no_grad():
            after = sum(float((stage(r[None])[0] - c).pow(2).sum()) for r, c in pairs)
        matched = left < TOLERANCES[route] or left <= (1 - MIN_CLOSED) * gap
        stages[demosaic] = (not matched, after if matched else left, stage)
        note[demosaic] = {"amount": round(float(stage.amount), 3), "trace_left": round(left, 3)}
        note[demosaic] |= {"mse_amount": round(nearest, 3), "relative_mse_gain": round(1 - after / before, 4)}
    chosen = min(DEMOSAICS, key=lambda demosaic: stages[demosaic][:2])
    return stages[chosen][2], {"demosaics": note}


def fit_amount(
    fit: PairedFit, cleans: list[Tensor], captures: list[Tensor], nearest: ColorFilterArray, route: str
) -> tuple[ColorFilterArray, float, float]:
    """Of :data:`AMOUNTS` and ``nearest``'s (the squared error's), the amount of ``nearest``'s layout and demosaic
    whose sampled simulation's trace (by ``route``) is nearest the captures'; the distance it leaves, and the
    distance without the stage."""
    pattern = nearest.pattern
    to_captures = distance_to(captures, pattern, route)

    def distance(amount: float) -> float:
        stage = ColorFilterArray(pattern, amount, nearest.demosaic)
        simulated = fit.profile.with_effects(stage).simulate(cleans, 0, stream="cfa-amount", eight_bit=fit.eight_bit)
        return to_captures(simulated)

    distances = {amount: distance(amount) for amount in sorted({0.0, *AMOUNTS, round(float(nearest.amount), 3)})}
    best = min((amount for amount in distances if amount > 0), key=distances.__getitem__)
    return ColorFilterArray(pattern, best, nearest.demosaic), distances[best], distances[0.0]


def judge_cfa(fit: PairedFit, stage: ColorFilterArray, route: str) -> tuple[Effect | None, dict[str, Any], str]:
    """``stage`` kept where it brings the sampled simulation's trace (by ``route``, over :data:`JUDGE_DRAWS` noise
    draws) toward the judged captures' (:data:`MIN_CLOSED`, :data:`TRACE_TOLERANCE`); the record and log line say
    by how much, with the share of the deterministic output's squared error it removes."""
    captures = [captured for _, captured in fit.evidence_pairs[0]]
    judged = judge_by_statistic(
        fit,
        stage,
        distance_to(captures, stage.pattern, route),
        stream="cfa-evidence",
        eight_bit=fit.eight_bit,
        tolerance=TOLERANCES[route],
        share=MIN_CLOSED,
        draws=JUDGE_DRAWS,
    )
    note: dict[str, Any] = {"kept": judged.kept, "demosaic": stage.demosaic, "amount": round(float(stage.amount), 3)}
    note |= judged.record("distance", f"the mosaic's {READS[route]} distance")
    line = (
        f"{stage.pattern} {stage.demosaic} at {float(stage.amount):.3f}: {READS[route]} distance to the captures' "
        f"{judged.without:.3f} simulated without, {judged.within:.3f} with; {judged.line_end()}"
    )
    return (stage if judged.kept else None), note, line


def distance_to(captures: Sequence[Tensor], pattern: str, route: str) -> Callable[[Sequence[Tensor]], float]:
    """How far a set of images is from ``captures`` in the mosaic's trace: the colour route's trace of ``pattern``
    (the absolute difference); the luma route's whole form (:func:`~camdegrade.measures.traces.mosaic_form.
    form_vector`, the Euclidean distance), not blue's site over red's alone."""
    if route == "luma":
        real = form_vector(captures)
        return lambda images: float((form_vector(images) - real).norm())
    trace = ROUTES[route]
    real_trace = trace(captures, pattern)
    return lambda images: abs(trace(images, pattern) - real_trace)


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
