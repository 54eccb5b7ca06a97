"""``fit_unpaired``: a camera profile from the camera's own photos and, optionally, a clean image set of *other*
scenes of similar content — no screen rig, no correspondence between the two sets.

Every stage is fitted by matching a distribution of the captures (an effects-only profile: no network):

- ``jpeg``: each capture's quality, read from its quantisation tables when it is a JPEG file, else from the
  quantisation lattice its pixels still hold (a JPEG saved again losslessly, with a warning); a mixture of the
  qualities found when they differ; kept only when the captures are compressed more than the clean images
  (:mod:`camdegrade.fitting.unpaired.steps.jpeg`);
- ``color``, ``tone``: white balance and a tone curve by quantile matching (local: :mod:`.steps.local_tone`);
- ``vignetting``: the captures' mean radial luma profile over the clean set's (over a flat field without one);
- ``blur``, ``sharpen``: the PSF and the unsharp mask whose simulation of the clean set has the captures' radial
  power spectrum (noise and codec simulated too, so the noise floor is not read as sharpness);
- ``frequency_response``: what every other stage leaves of that spectrum's mismatch (a phone's detail processing
  has no Gaussian-plus-unsharp shape), as a gain per radial band, kept where that is more than a floor and a
  response fitted on each half of the sets also brings the other half's spectrum closer;
- ``noise``: level per channel and intensity, spatial and chroma correlation, banding, from the captures' flat
  regions (:mod:`camdegrade.fitting.unpaired.steps.noise`), calibrated through the whole chain;
- ``learned_texture``: last, a small network trained against a patch critic for the texture no stage names, kept
  where held-out halves of the sets say so; only where each half holds enough patches
  (:mod:`camdegrade.fitting.two_sample.step`).

The fit runs the paired fit's loop of steps (:func:`~camdegrade.fitting.steps.base.run_steps`) over
:data:`UNPAIRED_STEPS`, each step judged by random halves of the two sets (:mod:`camdegrade.fitting.unpaired.judges`)
or its floor. Without a clean set only ``jpeg``, ``vignetting`` (against a flat field) and ``noise`` (simulated on
the captures smoothed) are fitted. Geometric stages are not identifiable without correspondence and are never fitted
(:data:`NOT_IDENTIFIABLE`). The profile records ``fitted['unpaired']``, how many images each side had and each
stage's evidence, and ``quality['unpaired_fidelity']``: the simulated clean set against the captures (flat-noise
ratio, band log2 power differences of the set means).
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import torch
from tqdm.auto import tqdm

from camdegrade._support.checks import check_seed
from camdegrade._support.files import check_writable
from camdegrade.effects import LearnedTexture
from camdegrade.effects._fitting import downscale
from camdegrade.effects.base import evenly_spaced
from camdegrade.errors import CamdegradeError, FitInterrupted
from camdegrade.fitting.record import machine_record
from camdegrade.fitting.steps.base import run_steps
from camdegrade.fitting.two_sample.step import LearnedTextureMatch
from camdegrade.fitting.unpaired.bench import Log, Measured, UnpairedFit, UnpairedStep
from camdegrade.fitting.unpaired.checkpoint import StepCheckpoint, check_checkpoint, fit_fingerprint
from camdegrade.fitting.unpaired.images import MIN_IMAGES, ImageSet, Source, check_count, load_images, load_sides
from camdegrade.fitting.unpaired.judges import band_spread, self_check_critic, self_check_warnings, unmeasured_bands
from camdegrade.fitting.unpaired.sensor import SensorStep, check_area_sensor, check_sensor_scale, with_sensor
from camdegrade.fitting.unpaired.steps.area_sensor import AreaSensorMatch
from camdegrade.fitting.unpaired.steps.color_tone import ColorToneMatch
from camdegrade.fitting.unpaired.steps.jpeg import JpegQuality
from camdegrade.fitting.unpaired.steps.local_tone import LocalToneMatch
from camdegrade.fitting.unpaired.steps.noise import NoiseMatch, flat_sums, own_check_noise
from camdegrade.fitting.unpaired.steps.response_refit import DetailResponseRefit
from camdegrade.fitting.unpaired.steps.spectrum import (
    SPECTRUM_SIDE,
    DetailResponseMatch,
    TransferMatch,
    centre_crop,
    log_spectrum,
    mean_spectrum,
)
from camdegrade.fitting.unpaired.steps.vignetting import RINGS, VignettingMatch, ring_profiles
from camdegrade.functional.optics.blur import blur_image
from camdegrade.measures.fidelity import BAND_EDGES, band_power
from camdegrade.profile import CameraProfile

__all__ = [
    "MIN_IMAGES",
    "NOT_IDENTIFIABLE",
    "UNPAIRED_EFFECTS",
    "UNPAIRED_OPTIONAL",
    "UNPAIRED_STEPS",
    "check_unpaired_effects",
    "fit_unpaired",
    "unpaired_fidelity",
]

#: The stages :func:`fit_unpaired` fits by default, in the order they are fitted; the learned texture stage last
#: (:mod:`camdegrade.fitting.two_sample.step`), where the sets are enough for it.
UNPAIRED_EFFECTS: tuple[str, ...] = (
    "resolution", "jpeg", "color", "tone", "vignetting", "noise", "blur", "sharpen", "frequency_response",
    LearnedTexture.name,
)  # fmt: skip
#: Stages :func:`fit_unpaired` fits only when asked for (``effects``): none since the learned texture stage is one.
UNPAIRED_OPTIONAL: tuple[str, ...] = ()
#: Stages that need to know where each clean pixel landed in the capture: an unpaired set cannot show them.
NOT_IDENTIFIABLE: dict[str, str] = {
    "misalignment": "a shift between clean image and capture is invisible without the same scene on both sides",
    "distortion": "the lens's radial warp needs straight scene lines or a correspondence to be seen",
    "chromatic_aberration": "a channel's scale is seen against the same scene's other channels at edges only "
    "with a reference; set statistics do not show it",
}
#: The noise is calibrated on at most ``NOISE_IMAGES`` clean images, whole (their flat pixels are selected as the
#: captures' are: a window chosen for its flatness would hold less texture than the captures' flat pixels do);
#: the spectrum compared on centre crops of at most ``SPECTRUM_IMAGES``.
NOISE_IMAGES = 16
SPECTRUM_IMAGES = 24
#: Colour, tone and vignetting are read from the images averaged down to this side (noise averaged out).
SMALL_SIDE = 256
#: Without a clean set the noise is simulated on the captures smoothed by a Gaussian of this sigma (px).
STAND_IN_SIGMA = 2.0


#: The unpaired fit's steps in the order they run, each with the label a progress bar shows: the chain before a
#: stage stands when it is fitted, so stages that depend on later ones are fitted again once those stand.
UNPAIRED_STEPS: tuple[tuple[str, UnpairedStep], ...] = (
    ("resolution", SensorStep()),
    ("jpeg", JpegQuality()),
    ("vignetting", VignettingMatch()),
    ("colour and tone", ColorToneMatch(test=False)),
    ("vignetting again", VignettingMatch(simulated=True)),
    ("noise", NoiseMatch()),
    ("blur and sharpening", TransferMatch()),
    ("area sensor, its upscale and sharpening", AreaSensorMatch()),
    ("colour and tone through the blur", ColorToneMatch()),
    ("local tone", LocalToneMatch()),
    ("vignetting through the blur", VignettingMatch(simulated=True)),
    ("noise again", NoiseMatch()),
    ("detail response", DetailResponseMatch()),
    ("noise through the detail response", NoiseMatch(refit=True)),
    ("detail response through the noise", DetailResponseRefit()),
    ("learned texture: trained on half A, judged on B", LearnedTextureMatch("half A")),
    ("learned texture: trained on half B, judged on A", LearnedTextureMatch("half B")),
    ("learned texture: trained on all", LearnedTextureMatch("all")),
)


def check_unpaired_effects(effects: Sequence[str]) -> list[str]:
    """``effects`` as a list, each one :func:`fit_unpaired` can fit; a ``ValueError`` naming the first that is
    not identifiable unpaired (and why) or unknown."""
    names = [effects] if isinstance(effects, str) else list(effects)
    for name in names:
        if name in NOT_IDENTIFIABLE:
            raise ValueError(f"effects: {name!r} cannot be fitted unpaired: {NOT_IDENTIFIABLE[name]}")
        if name not in UNPAIRED_EFFECTS + UNPAIRED_OPTIONAL:
            raise ValueError(f"effects must be names from {[*UNPAIRED_EFFECTS, *UNPAIRED_OPTIONAL]}, got {name!r}")
    return names


def fit_unpaired(
    captured: Source,
    clean: Source | None = None,
    *,
    effects: Sequence[str] = UNPAIRED_EFFECTS,
    seed: int = 0,
    sensor_scale: float | str = "auto",
    area_sensor: bool = False,
    max_images: int | None = None,
    strict: bool = False,
    progress: bool = False,
    name: str = "",
    description: str = "",
    log: Log | None = None,
    checkpoint: str | os.PathLike[str] | None = None,
    resume: bool = False,
) -> CameraProfile:
    """Fit an effects-only camera profile from the camera's photos ``captured`` and an optional ``clean`` set of
    other scenes of similar content (each a folder, or a list of ``(3, H, W)`` tensors, ``(H, W, 3)`` numpy arrays
    or PIL images; images of any sizes from 16 px a side).

    Args:
        effects: the stages to fit (default :data:`UNPAIRED_EFFECTS`); each is kept only where the captures differ
            from the clean set by more than its floor (see :mod:`camdegrade.fitting.unpaired.judges`).
        seed: the simulations' seed (same seed, same profile).
        sensor_scale: ``"auto"``: an upscale found from the captures (:func:`~camdegrade.fitting.steps.resolution.
            sensor_trace`); a number from 0.125 to 1: the sensor's resolution relative to the output, given (1: none).
        area_sensor: where ``sensor_scale`` is ``"auto"`` and no upscale shows, also search a sensor that reads its
            pixels' areas (:mod:`~camdegrade.fitting.unpaired.steps.area_sensor`; off by default: it read a blur in
            gamma as a sensor, and costs about a quarter more time).
        max_images: read at most this many images of each side.
        strict: refuse instead of warning: an unreadable file (before any fitting), or a result with a warning.
        progress: a progress bar over the steps.
        checkpoint: a ``.safetensors`` file the fit writes after each step (atomically: the file is always a whole
            checkpoint, :mod:`camdegrade.fitting.unpaired.checkpoint`). It is left in place after the fit: remove it
            once the profile is saved (``camdegrade fit`` does).
        resume: continue the fit ``checkpoint`` holds at the step after its last finished one. The result is the
            profile an uninterrupted fit gives (same bytes, but for ``fit_minutes``).

    Raises:
        PairsError: fewer than :data:`MIN_IMAGES` usable images on a side (unreadable files and images under 16 px
            a side are skipped), not a folder, a side without contrast, the same images on both sides; with
            ``strict``, a skipped file.
        CamdegradeError: with ``strict``, a result with a warning.
        CheckpointError: with ``resume``, a ``checkpoint`` that is not an unpaired fit's checkpoint, or one written for
            other images or options.
        FitInterrupted: Ctrl-C during a step, with a ``checkpoint`` (which holds the steps before it).
        FileNotFoundError: with ``resume``, no file at ``checkpoint``.
        TypeError, ValueError: an image of a list that is not an RGB image in [0, 1] or uint8 (named by its
            index), a seed that is not an int.
        ValueError: an effect that needs correspondence (:data:`NOT_IDENTIFIABLE`), or captures with too few flat
            pixels to measure their noise.
    """
    say = log or (lambda message: None)
    wanted = check_unpaired_effects(effects)
    steps = with_sensor(UNPAIRED_STEPS, check_sensor_scale(sensor_scale), check_area_sensor(area_sensor))
    for label, text in (("name", name), ("description", description)):
        if not isinstance(text, str):
            raise TypeError(f"{label} must be a str, got {label}={text!r} ({type(text).__name__})")
    check_seed(seed)
    path = check_checkpoint(checkpoint, resume)
    if path is not None:
        check_writable(path)
    started = time.perf_counter()
    captures, cleans, warnings = load_sides(captured, clean, max_images, strict)
    say(f"unpaired fit: {len(captures.images)} captures, {len(cleans.images) if cleans else 'no'} clean images")
    options = {"wanted": wanted, "seed": seed, "sensor_scale": sensor_scale, "max_images": max_images}
    fingerprint = fit_fingerprint(captures, cleans, steps, **options) if path else {}  # hashes every pixel
    saved = StepCheckpoint(path, fingerprint, [label for label, _ in steps])
    if resume:
        saved.read()
    fit = UnpairedFit(captures, cleans, measure(captures, cleans), wanted, seed, say)
    fit.warnings += warnings
    if resume:
        started -= saved.restore(fit)
    _run(steps, fit, saved, started, progress)
    profile = CameraProfile(None, fit.chain(), name=name, description=description)
    profile.quality = {"unpaired_fidelity": set_fidelity(fit)}
    fit.warnings += self_check_warnings(profile.quality["unpaired_fidelity"], wanted, with_clean=cleans is not None)
    notes = unmeasured_bands(profile.quality["unpaired_fidelity"], wanted, with_clean=cleans is not None)
    profile.fitted = _record(fit, time.perf_counter() - started) | ({"notes": notes} if notes else {})
    for line in [f"note: {note}" for note in notes] + [f"warning: {warning}" for warning in fit.warnings]:
        say(line)
    if strict and fit.warnings:
        raise CamdegradeError(f"{fit.warnings[0]}; strict: no profile (fix the input, or run without strict)")
    return profile


def _run(
    steps: Sequence[tuple[str, UnpairedStep]], fit: UnpairedFit, saved: StepCheckpoint, started: float, progress: bool
) -> None:
    """The steps ``saved`` has not done, each written to its file once done (:meth:`StepCheckpoint.save`); an
    interruption (Ctrl-C) during a step ends the fit with :class:`~camdegrade.errors.FitInterrupted` naming the file
    that holds the steps before it (re-raised as it is without a file)."""

    def done(count: int) -> None:
        saved.save(fit, count, time.perf_counter() - started)

    try:
        with tqdm(total=len(steps), initial=saved.done, desc="unpaired fit", unit="step", disable=not progress) as bar:
            run_steps(_shown(steps, saved.done, bar, done), fit)
    except (KeyboardInterrupt, FitInterrupted):
        if saved.path is None:
            raise
        raise FitInterrupted(saved.interrupted()) from None


#: Where a profile's simulation of the clean set agrees with the captures in the statistics the fit matches: the
#: flat-noise ratio inside this range and every band's log2 power difference within this many log2 units.
NOISE_RATIO_RANGE = (0.8, 1.25)
BAND_TOLERANCE = 0.5


def unpaired_fidelity(
    profile: CameraProfile, captured: Source, clean: Source, *, seed: int = 0, max_images: int | None = None
) -> dict[str, Any]:
    """The statistics :func:`fit_unpaired` matches, of ``profile``'s simulation of ``clean`` against ``captured``:
    what it records as ``quality["unpaired_fidelity"]`` (the same images, crops and seeds give the same numbers),
    plus ``agrees``: the noise ratio within :data:`NOISE_RATIO_RANGE` and every band within
    :data:`BAND_TOLERANCE`. The unpaired diagnosis reports it beside its own statistics."""
    captures, cleans = load_images(captured, "captured", max_images), load_images(clean, "clean", max_images)
    check_count(captures, "captured")
    check_count(cleans, "clean")
    fit = UnpairedFit(captures, cleans, measure(captures, cleans), [], seed, lambda message: None)
    fidelity = set_fidelity(fit, profile)
    low, high = NOISE_RATIO_RANGE
    ratio = fidelity["noise_ratio"]
    fidelity["agrees"] = (ratio is None or low <= ratio <= high) and all(
        abs(value) <= BAND_TOLERANCE for value in fidelity["bands"]
    )
    return fidelity


def set_fidelity(fit: UnpairedFit, profile: CameraProfile | None = None) -> dict[str, Any]:
    """The simulated clean set (through ``profile``, or the fitted chain) against the captures: flat-noise ratio
    (pooled std), the set means' log2 band power differences
    (:data:`~camdegrade.measures.fidelity.BAND_EDGES`), the spectrum mismatch and, with a clean set, a fresh
    image-only critic (:func:`~camdegrade.fitting.unpaired.judges.self_check_critic`)."""
    chain = fit.chain() if profile is None else profile
    noisy_std, real_std = own_check_noise(fit, fit.simulate(chain, fit.sets.noise_crops, "unpaired-check"))
    ratio = noisy_std / real_std if real_std > 0 else math.nan
    sims = fit.simulate(chain, fit.sets.spectrum_crops, "unpaired-check")
    sim_bands = torch.stack([band_power(image)[0] for image in sims]).clamp_min(1e-8).log2()
    real_crops = [centre_crop(image, SPECTRUM_SIDE) for image in fit.captures.images]
    real_bands = torch.stack([band_power(image)[0] for image in real_crops]).clamp_min(1e-8).log2()
    mismatch = float((mean_spectrum(sims) - fit.sets.real_spectrum).pow(2).mean())
    return {
        "noise_ratio": round(ratio, 3) if math.isfinite(ratio) else None,
        "bands": [round(float(value), 3) for value in sim_bands.mean(0) - real_bands.mean(0)],
        "band_spread": band_spread(real_bands, sim_bands, fit.seed),  # what content alone moves each band by
        "band_edges": list(BAND_EDGES),
        "spectrum_mismatch": round(mismatch, 4),
        # without a clean set the simulation runs on the captures smoothed, whose lost detail a critic would read
        "critic_image_only": self_check_critic(
            lambda images: fit.simulate(chain, images, "unpaired-critic"), fit.cleans.images, fit.captures.images
        )
        if fit.cleans
        else None,
    }


def measure(captures: ImageSet, cleans: ImageSet | None) -> Measured:
    """What the fit measures of its sets once (:class:`~camdegrade.fitting.unpaired.bench.Measured`); without a
    clean set the noise and the spectrum are simulated on the captures smoothed (:data:`STAND_IN_SIGMA`)."""
    stand_ins = cleans.images if cleans else [blur_image(image, STAND_IN_SIGMA) for image in captures.images]
    small_captures = [downscale(image, SMALL_SIDE) for image in captures.images]
    small_cleans = [downscale(image, SMALL_SIDE) for image in cleans.images] if cleans else []
    real_spectra = torch.stack([log_spectrum(centre_crop(image, SPECTRUM_SIDE)) for image in captures.images])
    return Measured(
        noise_crops=evenly_spaced(stand_ins, NOISE_IMAGES),
        spectrum_crops=[centre_crop(image, SPECTRUM_SIDE) for image in evenly_spaced(stand_ins, SPECTRUM_IMAGES)],
        real_noise=flat_sums(captures.images),
        small_captures=small_captures,
        small_cleans=small_cleans,
        real_rings=ring_profiles(small_captures),
        clean_rings=ring_profiles(small_cleans) if cleans else torch.zeros(0, RINGS, dtype=torch.float64),
        real_spectra=real_spectra,
        real_spectrum=real_spectra.mean(0),
    )


def _record(fit: UnpairedFit, seconds: float) -> dict[str, Any]:
    """The profile's ``fitted``: the sets, every stage's evidence, what was kept and why the rest was not."""
    skipped = fit.captures.skipped + (fit.cleans.skipped if fit.cleans else [])
    out = {
        "unpaired": True,
        "captures": len(fit.captures.images),
        "clean_images": len(fit.cleans.images) if fit.cleans else 0,
        "unreadable": skipped,
        "effects": fit.records,
        "kept": [effect.name for effect in fit.chain()],
        "not_fitted": fit.not_fitted,
        "not_identifiable": sorted(NOT_IDENTIFIABLE),
        "seed": fit.seed,
        "fit_minutes": round(seconds / 60, 2),
        **machine_record(),
    }
    if fit.warnings:
        out["warnings"] = list(fit.warnings)
    return out


def _shown(
    steps: Sequence[tuple[str, UnpairedStep]], start: int, bar: tqdm, done: Callable[[int], None]
) -> Iterator[UnpairedStep]:
    """``steps`` from index ``start`` on, one after the other, each shown on ``bar`` while it runs; ``done(count)``
    once the first ``count`` steps are done."""
    for count, (label, step) in enumerate(steps[start:], start + 1):
        bar.set_postfix_str(label)
        yield step
        bar.update(1)
        done(count)
