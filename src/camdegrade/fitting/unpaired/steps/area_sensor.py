"""A sensor of fewer pixels that reads each pixel's area, the ISP's upscale and the sharpening after it (issue 43).

A linear blur widens strong steps and thin lines alike. A camera whose sensor has fewer pixels than its output,
without an optical low-pass filter, upscaled and then sharpened, keeps steps crisp and spreads thin strokes: City100's
iPhone X reads 3.10 px for steps (a Gaussian of σ 1.25) and 4.39 px for thin lines (σ 1.75), and text breaks into
blobs (docs/results.md, *The unpaired fit's softness*). Where no upscale leaves a periodic trace (the resolution
step's), this step tries such a sensor: an optical blur, a :class:`~camdegrade.effects.Resolution` with
``sample="area"`` (scale and upsampling kernel) and an unsharp mask after its upscale, replacing the blur and
sharpening fitted before. Candidates are judged by what texture (aliasing, noise, codec) cannot fake: the median
width of strong steps (:func:`~camdegrade.functional.analysis.edges.step_widths`) and of thin lines
(:func:`~camdegrade.functional.analysis.edges.line_widths`) of the simulated clean set against the captures', and
the spectrum's bands below :data:`SHAPE_TOP` cycles/pixel (above it the captures hold the texture later stages make).
A sensor found on each half of the sets must bring the *other* half's statistics closer than the chain without it
(:data:`KEEP_GAIN`): a difference of scenes between random halves does not carry over. City100's iPhone X is refused:
its best sensor brings the lines close but leaves the steps too wide (docs/results.md, *An area-sampling sensor in
the unpaired fit*)."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from itertools import product
from typing import Any, ClassVar

import torch
from torch import Tensor

from camdegrade.effects import Blur, Effect, Resolution, Sharpen
from camdegrade.fitting.steps.base import Verdict
from camdegrade.fitting.unpaired.bench import UnpairedFit, UnpairedStep
from camdegrade.fitting.unpaired.steps.spectrum import (
    HALVES,
    REFERENCE_BANDS,
    SPECTRUM_EDGES,
    SPECTRUM_GAIN,
    SPECTRUM_SIDE,
    centre_crop,
    log_spectrum,
)
from camdegrade.functional.analysis.edges import line_widths, pooled_median, step_widths

__all__ = ["AreaSensorMatch", "SensorCandidate", "SetWidths", "distance", "set_widths"]

#: The grid each coordinate of a candidate is searched over: the sensor's resolution relative to the output, the
#: ISP's upsampling kernel, an optical blur before the sensor (Gaussian σ, px), and the unsharp mask after the
#: upscale (σ px, amount).
SCALES = (1 / 3, 0.4, 1 / 2, 2 / 3)
KERNELS = ("bicubic", "catmull_rom", "lanczos", "bilinear")
PRE_SIGMAS = (0.0, 0.5, 0.8, 1.0)
SHARPEN_SIGMAS = (1.0, 2.0)
SHARPEN_AMOUNTS = (0.0, 0.5, 1.0, 1.5, 2.0, 3.0)
#: The coordinates searched jointly, then rounds of the search along each coordinate (the others held) in turn.
JOINT = ("scale", "amount", "sharpen_sigma")
PASSES = 1
#: The distance (:func:`distance`): each median width's difference in units of ``WIDTH_UNIT`` px, squared, plus the
#: mean squared log2 band power difference below ``SHAPE_TOP`` cycles/pixel in units of ``SPECTRUM_UNIT`` (0.1 log2
#: per band weighs as 0.1 px).
WIDTH_UNIT = 0.1
SPECTRUM_UNIT = 0.01
SHAPE_TOP = 0.25
#: A sensor is kept where the chain without it is farther than ``KEEP_FLOOR`` from the captures on both halves and
#: the sensor fitted on the other half takes that below :data:`KEEP_GAIN` of it.
KEEP_FLOOR = 1.0
KEEP_GAIN = SPECTRUM_GAIN
#: Fewer steps or lines than this on a side: not measured, no sensor tried.
MIN_COUNT = 50


@dataclass(frozen=True)
class SensorCandidate:
    """An optical blur (σ px, 0: none), an area-sampling sensor of ``scale`` upsampled by ``kernel``, and an unsharp
    mask after the upscale (σ px, amount; 0: none)."""

    scale: float = 1 / 2
    kernel: str = "bicubic"
    pre: float = 0.0
    sharpen_sigma: float = 1.0
    amount: float = 0.0

    def stages(self) -> dict[str, Effect | None]:
        return {
            Blur.name: Blur(self.pre) if self.pre > 0 else None,
            Resolution.name: Resolution(self.scale, self.kernel, "area"),
            Sharpen.name: Sharpen(self.sharpen_sigma, self.amount) if self.amount > 0 else None,
        }


@dataclass(frozen=True)
class SetWidths:
    """Per image: its step widths, its line widths and its band log2 powers (:func:`log_spectrum`)."""

    steps: list[Tensor]
    lines: list[Tensor]
    spectra: Tensor


def set_widths(images: Sequence[Tensor]) -> SetWidths:
    """The :class:`SetWidths` of ``images`` (the spectrum on their centre crops, as the fit reads it)."""
    spectra = torch.stack([log_spectrum(centre_crop(image, SPECTRUM_SIDE)) for image in images])
    return SetWidths([step_widths(image) for image in images], [line_widths(image) for image in images], spectra)


def _shape_bands() -> int:
    """How many of :func:`log_spectrum`'s bands lie below :data:`SHAPE_TOP`."""
    return sum(1 for top in SPECTRUM_EDGES[REFERENCE_BANDS + 1 :] if top <= SHAPE_TOP)


def distance(simulated: SetWidths, real: SetWidths, part: slice = slice(None)) -> tuple[float, dict[str, float]]:
    """How far the ``part`` of the simulated set is from the ``part`` of the captures: the two median widths'
    differences (in :data:`WIDTH_UNIT`) squared plus the low bands' mean squared difference (in
    :data:`SPECTRUM_UNIT`); infinite where a side has fewer than :data:`MIN_COUNT` steps or lines. And its parts."""
    parts: dict[str, float] = {}
    total = 0.0
    for name in ("steps", "lines"):
        (sim, count), (want, _) = (pooled_median(getattr(widths, name)[part]) for widths in (simulated, real))
        parts[name] = round(sim - want, 3) if count >= MIN_COUNT and math.isfinite(sim - want) else math.inf
        total += (parts[name] / WIDTH_UNIT) ** 2
    bands = _shape_bands()
    mismatch = float((simulated.spectra[part, :bands].mean(0) - real.spectra[part, :bands].mean(0)).pow(2).mean())
    parts["spectrum"] = round(mismatch, 4)
    return total + mismatch / SPECTRUM_UNIT, parts


def _grid(fit: UnpairedFit) -> tuple[tuple[str, tuple], ...]:
    """Each coordinate's values; the blur and the sharpening only where they are asked for."""
    return (
        ("scale", SCALES),
        ("amount", SHARPEN_AMOUNTS if fit.wants(Sharpen) else (0.0,)),
        ("pre", PRE_SIGMAS if fit.wants(Blur) else (0.0,)),
        ("kernel", KERNELS),
        ("sharpen_sigma", SHARPEN_SIGMAS if fit.wants(Sharpen) else (1.0,)),
    )


def descend(score: Callable[[SensorCandidate], float], grid: Sequence[tuple[str, tuple]]) -> SensorCandidate:
    """The candidate of least ``score``: every combination of the coordinates named in :data:`JOINT` (they trade
    against each other: a smaller sensor and more sharpening can leave the same step width), the others at
    :class:`SensorCandidate`'s defaults; then :data:`PASSES` rounds of a search along each coordinate of ``grid`` in
    turn, the others held (ties keep the earlier)."""
    values = dict(grid)
    joint = [dict(zip(JOINT, combination, strict=True)) for combination in product(*(values[name] for name in JOINT))]
    best = min((replace(SensorCandidate(), **fields) for fields in joint), key=score)
    least = score(best)
    for _ in range(PASSES):
        for field, options in grid:
            for value in options:
                candidate = replace(best, **{field: value})
                value_score = score(candidate)
                if value_score < least:
                    best, least = candidate, value_score
    return best


@dataclass(frozen=True)
class SensorProposal:
    """The captures' widths, the chain's without a sensor, the candidate found on each half of the sets, and
    ``widths(candidate)`` (its simulation's :class:`SetWidths`, each candidate simulated once: ``simulated``)."""

    real: SetWidths
    without: SetWidths
    found: dict[str, SensorCandidate]
    widths: Callable[[SensorCandidate], SetWidths]
    simulated: dict[SensorCandidate, SetWidths]


@dataclass(frozen=True)
class AreaSensorMatch(UnpairedStep):
    """The area-sensor step (it needs the clean set; it runs where ``search`` asks for it and the resolution step
    kept no sensor and was given no scale): see the module's docstring. Off by default (``fit_unpaired``'s
    ``area_sensor``): on City100 it is refused, a Gaussian blur of gamma-encoded values read as a sensor of a third
    of the pixels, and it costs the 100-capture bench about a quarter more CPU time."""

    name: ClassVar[str] = "area_sensor"
    kinds: ClassVar[tuple[type[Effect], ...]] = (Resolution,)
    needs_clean: ClassVar[bool] = True
    search: bool = False

    def applies(self, fit: UnpairedFit) -> bool:
        given = fit.records.get(Resolution.name, {}).get("given")
        return self.search and fit.stages.get(Resolution.name) is None and not given

    def propose(self, fit: UnpairedFit) -> SensorProposal | Verdict:
        """No search where a side has too few steps or lines, or where the chain without a sensor is already within
        :data:`KEEP_FLOOR` of the captures on a half (no sensor could be kept: the judge's rule)."""
        crops = fit.sets.spectrum_crops
        real = set_widths(fit.captures.images)
        without = set_widths(fit.simulate(fit.chain(), crops, "unpaired-sensor"))
        counts = {name: min(len(torch.cat(getattr(s, name))) for s in (real, without)) for name in ("steps", "lines")}
        if min(counts.values()) < MIN_COUNT:
            return Verdict({"kept": False, "why": f"fewer than {MIN_COUNT} steps or lines on a side", **counts})
        befores = [distance(without, real, part)[0] for part in HALVES]
        if min(befores) <= KEEP_FLOOR:
            why = f"the chain without a sensor is within {KEEP_FLOOR} of the captures on a half"
            return Verdict({"kept": False, "why": why, "halves": [_rounded(value) for value in befores]})
        simulated: dict[SensorCandidate, SetWidths] = {}

        def widths(candidate: SensorCandidate) -> SetWidths:
            if candidate not in simulated:
                images = fit.simulate(fit.chain(**candidate.stages()), crops, "unpaired-sensor")
                simulated[candidate] = set_widths(images)
            return simulated[candidate]

        found = {
            label: descend(lambda candidate, part=part: distance(widths(candidate), real, part)[0], _grid(fit))
            for label, part in (("half A", HALVES[0]), ("half B", HALVES[1]))
        }
        return SensorProposal(real, without, found, widths, simulated)

    def judge(self, fit: UnpairedFit, proposal: SensorProposal) -> dict[str, Any]:
        """Kept where each half's sensor takes the other half's distance below :data:`KEEP_GAIN` of the chain's
        without it (above :data:`KEEP_FLOOR`); then found on the whole sets."""
        real, checks = proposal.real, []
        for fitted_on, checked_on in (("half A", HALVES[1]), ("half B", HALVES[0])):
            before = distance(proposal.without, real, checked_on)[0]
            checks.append((before, distance(proposal.widths(proposal.found[fitted_on]), real, checked_on)[0]))
        kept = all(before > KEEP_FLOOR and after < KEEP_GAIN * before for before, after in checks)
        record: dict[str, Any] = {
            "kept": kept,
            "halves": [[_rounded(before), _rounded(after)] for before, after in checks],
            "without": _finite(distance(proposal.without, real)[1]),
            "found_on_halves": [_described(proposal, proposal.found[label]) for label in ("half A", "half B")],
            "captures": {name: _rounded(pooled_median(getattr(real, name))[0]) for name in ("steps", "lines")},
        }
        if kept:
            chosen = descend(lambda candidate: distance(proposal.widths(candidate), real)[0], _grid(fit))
            record["chosen"] = _described(proposal, chosen)
            fit.keep(None, Blur, Sharpen)
            for stage in chosen.stages().values():
                fit.keep(stage)
        record["simulations"] = len(proposal.simulated)
        fit.say(f"area sensor: {record}")
        return record


def _described(proposal: SensorProposal, candidate: SensorCandidate) -> dict[str, Any]:
    """``candidate``'s fields and its simulation's differences from the captures on the whole sets."""
    return {**asdict(candidate), "differences": _finite(distance(proposal.widths(candidate), proposal.real)[1])}


def _rounded(value: float) -> float | None:
    return round(value, 3) if math.isfinite(value) else None


def _finite(parts: dict[str, float]) -> dict[str, float | None]:
    """``parts`` for a record (JSON has no infinity: ``None``)."""
    return {name: _rounded(value) for name, value in parts.items()}
