"""``fit_unpaired``: a camera profile from the camera's own photos and, optionally, a clean image set of *other*
scenes of similar content — no screen rig, no correspondence between the two sets.

Every stage is fitted by matching a distribution of the captures (an effects-only profile: no network):

- ``jpeg``: each capture's quality, read from its quantisation tables when it is a JPEG file, else from the
  quantisation lattice its pixels still hold (a JPEG saved again losslessly, with a warning); a mixture of the
  qualities found when they differ; kept only when the captures are compressed more than the clean images
  (:mod:`camdegrade.fitting._unpaired_jpeg`);
- ``color``, ``tone``: white-balance gains and a tone curve by quantile matching of the two sets;
- ``vignetting``: the captures' mean radial luma profile over the clean set's (over a flat field without one);
- ``blur``, ``sharpen``: the PSF and the unsharp mask whose simulation of the clean set has the captures' radial
  power spectrum (noise and codec simulated too, so the noise floor is not read as sharpness);
- ``frequency_response``: what every other stage leaves of that spectrum's mismatch (a phone's detail processing
  has no Gaussian-plus-unsharp shape), as a gain per radial band, kept where that is more than a floor and a
  response fitted on each half of the sets also brings the other half's spectrum closer;
- ``noise``: level per channel and intensity, spatial and chroma correlation, banding, from the captures' flat
  regions (:mod:`camdegrade.fitting._unpaired_noise`), calibrated through the whole chain.

Without a clean set only ``jpeg``, ``vignetting`` (against a flat field) and ``noise`` (simulated on the captures
smoothed) are fitted. Geometric stages are not identifiable without correspondence and are never fitted
(:data:`NOT_IDENTIFIABLE`). The profile records ``fitted['unpaired']``, how many images each side had and each
stage's evidence, and ``quality['unpaired_fidelity']``: the simulated clean set against the captures (flat-noise
ratio, band log2 power differences of the set means).
"""

from __future__ import annotations

import math
import platform
import time
from collections.abc import Callable, Sequence
from typing import Any

import torch
from torch import Tensor
from tqdm.auto import tqdm

from camdegrade._profile_format.header import running_versions
from camdegrade._seeds import derived_generator
from camdegrade._version import __version__
from camdegrade.effects import (
    JPEG,
    Blur,
    ChromaticAberration,
    Color,
    Distortion,
    Effect,
    FrequencyResponse,
    Misalignment,
    Noise,
    Resolution,
    Sharpen,
    Tone,
    Vignetting,
)
from camdegrade.effects._fitting import downscale
from camdegrade.effects.base import evenly_spaced
from camdegrade.fitting._distribution_match import (
    RINGS,
    SHARPEN_SIGMA,
    SPECTRUM_SIDE,
    band_centres,
    centre_crop,
    fit_color_tone,
    fit_detail_response,
    fit_transfer,
    fit_vignetting,
    log_spectrum,
    mean_spectrum,
    ring_profiles,
)
from camdegrade.fitting._unpaired_images import MIN_IMAGES, ImageSet, Source, check_count, load_images
from camdegrade.fitting._unpaired_jpeg import fit_codec
from camdegrade.fitting._unpaired_noise import fit_noise_unpaired, flat_sums
from camdegrade.fitting.resolution import find_sensor
from camdegrade.functional.blur import blur_image
from camdegrade.measures.fidelity import BAND_EDGES, band_power
from camdegrade.profile import CameraProfile

__all__ = ["MIN_IMAGES", "NOT_IDENTIFIABLE", "UNPAIRED_EFFECTS", "fit_unpaired", "unpaired_fidelity"]

#: The stages :func:`fit_unpaired` fits by default, in the order they are fitted.
UNPAIRED_EFFECTS: tuple[str, ...] = tuple(
    kind.name for kind in (Resolution, JPEG, Color, Tone, Vignetting, Noise, Blur, Sharpen, FrequencyResponse)
)
#: Stages that need to know where each clean pixel landed in the capture: an unpaired set cannot show them.
NOT_IDENTIFIABLE: dict[str, str] = {
    Misalignment.name: "a shift between clean image and capture is invisible without the same scene on both sides",
    Distortion.name: "the lens's radial warp needs straight scene lines or a correspondence to be seen",
    ChromaticAberration.name: "a channel's scale is seen against the same scene's other channels at edges only "
    "with a reference; set statistics do not show it",
}
#: The stages' order in the fitted chain (physical: optics, sensor, ISP, codec; the ISP's upscale last before the
#: codec, so the sensor's noise and the ISP's sharpening are upsampled with the image).
CHAIN_ORDER = tuple(
    kind.name for kind in (Blur, Vignetting, Noise, Color, Tone, Sharpen, FrequencyResponse, Resolution, JPEG)
)
#: The noise is calibrated on at most ``NOISE_IMAGES`` clean images, whole (their flat pixels are selected as the
#: captures' are: a window chosen for its flatness would hold less texture than the captures' flat pixels do);
#: the spectrum compared on centre crops of at most ``SPECTRUM_IMAGES``.
NOISE_IMAGES = 16
SPECTRUM_IMAGES = 24
#: Colour, tone and vignetting are read from the images averaged down to this side (noise averaged out).
SMALL_SIDE = 256
#: Knots per axis of the detail response: 0.025 cycles/pixel apart, finer than the narrowest band it is fitted on.
RESPONSE_KNOTS = 21
#: Without a clean set the noise is simulated on the captures smoothed by a Gaussian of this sigma (px).
STAND_IN_SIGMA = 2.0

Log = Callable[[str], None]


def _radial_response(log2_gains: Tensor) -> FrequencyResponse:
    """The detail response of amplitude gains ``2 ** log2_gains`` at the bands' centres (1 at the reference's)."""
    gains = [1.0, *log2_gains.exp2().tolist()]
    return FrequencyResponse.from_radial(band_centres().tolist(), gains, knots=RESPONSE_KNOTS)


def check_unpaired_effects(effects: Sequence[str]) -> list[str]:
    """``effects`` as a list, each one :func:`fit_unpaired` can fit; a ``ValueError`` naming the first that is
    not identifiable unpaired (and why) or unknown."""
    names = [effects] if isinstance(effects, str) else list(effects)
    for name in names:
        if name in NOT_IDENTIFIABLE:
            raise ValueError(f"effects: {name!r} cannot be fitted unpaired: {NOT_IDENTIFIABLE[name]}")
        if name not in UNPAIRED_EFFECTS:
            raise ValueError(f"effects must be names from {list(UNPAIRED_EFFECTS)}, got {name!r}")
    return names


def fit_unpaired(
    captured: Source,
    clean: Source | None = None,
    *,
    effects: Sequence[str] = UNPAIRED_EFFECTS,
    seed: int = 0,
    max_images: int | None = None,
    progress: bool = False,
    name: str = "",
    description: str = "",
    log: Log | None = None,
) -> CameraProfile:
    """Fit an effects-only camera profile from the camera's photos ``captured`` and an optional ``clean`` set of
    other scenes of similar content (each a folder or a list of ``(3, H, W)`` tensors, images of any sizes).

    Args:
        effects: the stages to fit (default :data:`UNPAIRED_EFFECTS`); each is kept only where the captures differ
            from the clean set by more than its floor (see :mod:`camdegrade.fitting._distribution_match`).
        seed: the simulations' seed (same seed, same profile).
        max_images: read at most this many images of each side.
        progress: a progress bar over the steps.

    Raises:
        PairsError: fewer than :data:`MIN_IMAGES` readable images on a side, or not a folder.
        ValueError: an effect that needs correspondence (:data:`NOT_IDENTIFIABLE`), or captures with too few flat
            pixels to measure their noise.
    """
    say = log or (lambda message: None)
    wanted = check_unpaired_effects(effects)
    for label, text in (("name", name), ("description", description)):
        if not isinstance(text, str):
            raise TypeError(f"{label} must be a str, got {label}={text!r} ({type(text).__name__})")
    started = time.perf_counter()
    captures = load_images(captured, "captured", max_images)
    check_count(captures, "captured")
    cleans = load_images(clean, "clean", max_images) if clean is not None else None
    if cleans is not None:
        check_count(cleans, "clean")
    say(f"unpaired fit: {len(captures.images)} captures, {len(cleans.images) if cleans else 'no'} clean images")
    fit = _UnpairedFit(captures, cleans, wanted, seed, say)
    with tqdm(total=len(fit.steps), desc="unpaired fit", unit="step", disable=not progress) as bar:
        for label, step in fit.steps:
            bar.set_postfix_str(label)
            step()
            bar.update(1)
    profile = CameraProfile(None, fit.chain(), name=name, description=description)
    profile.fitted = fit.record(time.perf_counter() - started)
    profile.quality = {"unpaired_fidelity": fit.fidelity()}
    for warning in fit.warnings:
        say(f"warning: {warning}")
    return profile


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
    fidelity = _UnpairedFit(captures, cleans, [], seed, lambda message: None).fidelity(profile)
    low, high = NOISE_RATIO_RANGE
    ratio = fidelity["noise_ratio"]
    fidelity["agrees"] = (ratio is None or low <= ratio <= high) and all(
        abs(value) <= BAND_TOLERANCE for value in fidelity["bands"]
    )
    return fidelity


class _UnpairedFit:
    """The state of one unpaired fit: the stages so far, each step's notes, and the sets it simulates."""

    def __init__(self, captures: ImageSet, cleans: ImageSet | None, wanted: list[str], seed: int, say: Log) -> None:
        self.captures, self.cleans, self.wanted, self.seed, self.say = captures, cleans, wanted, seed, say
        self.stages: dict[str, Effect] = {}
        self.notes: dict[str, Any] = {}
        self.not_fitted: dict[str, str] = {}
        self.warnings: list[str] = []
        stand_ins = cleans.images if cleans else [blur_image(image, STAND_IN_SIGMA) for image in captures.images]
        self.noise_crops = evenly_spaced(stand_ins, NOISE_IMAGES)
        self.spectrum_crops = [centre_crop(image, SPECTRUM_SIDE) for image in evenly_spaced(stand_ins, SPECTRUM_IMAGES)]
        self.real_noise = flat_sums(captures.images)
        self.small_captures = [downscale(image, SMALL_SIDE) for image in captures.images]
        self.small_cleans = [downscale(image, SMALL_SIDE) for image in cleans.images] if cleans else []
        self.real_rings = ring_profiles(self.small_captures)
        self.clean_rings = ring_profiles(self.small_cleans) if cleans else torch.zeros(0, RINGS, dtype=torch.float64)
        self.real_spectra = torch.stack([log_spectrum(centre_crop(image, SPECTRUM_SIDE)) for image in captures.images])
        self.real_spectrum = self.real_spectra.mean(0)
        self.steps: list[tuple[str, Callable[[], None]]] = [
            ("resolution", self.fit_resolution),
            ("jpeg", self.fit_jpeg),
            ("vignetting", lambda: self.fit_vignetting(simulated=False)),
            ("colour and tone", lambda: self.fit_color_tone(test=False)),
            ("vignetting again", lambda: self.fit_vignetting(simulated=True)),
            ("noise", self.fit_noise),
            ("blur and sharpening", self.fit_transfer),
            ("colour and tone through the blur", lambda: self.fit_color_tone(test=True)),
            ("vignetting through the blur", lambda: self.fit_vignetting(simulated=True)),
            ("noise again", self.fit_noise),
            ("detail response", self.fit_response),
            ("noise through the detail response", self.refit_noise),
        ]

    # -- the chain and its simulation ------------------------------------------------------------------------------

    def chain(self, **replaced: Effect | None) -> list[Effect]:
        stages = {**self.stages, **replaced}
        return [stages[key] for key in CHAIN_ORDER if stages.get(key) is not None]

    def simulate(self, chain: list[Effect] | CameraProfile, images: Sequence[Tensor], stream: str) -> list[Tensor]:
        """``images`` through ``chain`` (image ``i`` seeded by ``(seed, stream, i)``), stored as 8-bit values."""
        profile = chain if isinstance(chain, CameraProfile) else CameraProfile(None, chain)
        out = []
        with torch.no_grad():
            for index, image in enumerate(images):
                batch = image[None]
                params = profile.make_params(batch.shape, derived_generator(self.seed, stream, index))
                out.append(profile(batch, params)[0].mul(255).round().div(255))
        return out

    def stages_after(self, kind: type[Effect]) -> list[str]:
        """The kept stages that come after ``kind``'s place in the chain."""
        later = CHAIN_ORDER[CHAIN_ORDER.index(kind.name) + 1 :]
        return [name for name in later if self.stages.get(name) is not None]

    def wants(self, *kinds: type[Effect]) -> bool:
        """Whether any of these stages is to be fitted."""
        return any(kind.name in self.wanted for kind in kinds)

    def keep(self, stage: Effect) -> None:
        self.stages[stage.name] = stage

    def _skip(self, kinds: Sequence[type[Effect]], reason: str) -> None:
        for kind in kinds:
            if self.wants(kind):
                self.not_fitted[kind.name] = reason

    # -- steps -----------------------------------------------------------------------------------------------------

    def fit_resolution(self) -> None:
        """An upscale the captures show and the clean set does not (:func:`~camdegrade.fitting.resolution.
        find_sensor`; without a clean set, the captures' trace alone): first, so every later stage is fitted
        through it."""
        if not self.wants(Resolution):
            return
        cleans = self.cleans.images if self.cleans else None
        then = "every later stage is fitted through it (the profile has no network)"
        stage, self.notes[Resolution.name] = find_sensor(cleans, self.captures.images, self.say, then=then)
        if stage is not None:
            self.keep(stage)

    def fit_jpeg(self) -> None:
        """The codec stage (:func:`~camdegrade.fitting._unpaired_jpeg.fit_codec`): before every stage fitted through
        the chain, since its quality is read from the files or their pixels, not fitted."""
        if not self.wants(JPEG):
            return
        stage, self.notes[JPEG.name], warnings, line = fit_codec(self.captures, self.cleans)
        self.say(line)
        self.warnings += warnings
        if stage is None:
            self._skip([JPEG], self.notes[JPEG.name]["reason"])
        else:
            self.keep(stage)

    def fit_color_tone(self, *, test: bool) -> None:
        if not self.wants(Color, Tone):
            return
        if self.cleans is None:
            self._skip([Color, Tone], "needs a clean set (--clean)")
            return
        sources = self.simulate(self.deterministic(optics_only=True), self.small_cleans, "unpaired-deterministic")
        color, tone, notes = fit_color_tone(self.small_captures, sources, self.seed, test=test)
        self.notes["color_tone"] = notes
        for kind, stage in ((Color, color), (Tone, tone)):
            self.stages.pop(kind.name, None)
            if self.wants(kind) and stage is not None:
                self.keep(stage)
        self.say(f"colour and tone: gains {notes['gains']}, tone curve change {notes['tone_change']}")

    def fit_vignetting(self, *, simulated: bool) -> None:
        if not self.wants(Vignetting) or (simulated and self.cleans is None):
            return

        def simulate(vignetting: Vignetting) -> Tensor:
            chain = self.deterministic(vignetting=vignetting)
            return ring_profiles(self.simulate(chain, self.small_cleans, "unpaired-deterministic"))

        shape = tuple(int(v) for v in torch.tensor([list(i.shape[-2:]) for i in self.captures.images]).median(0).values)
        vignetting, notes = fit_vignetting(
            self.real_rings, self.clean_rings, shape, simulate if simulated else None, self.seed
        )
        self.notes[Vignetting.name] = notes
        self.stages.pop(Vignetting.name, None)
        if vignetting is not None:
            self.keep(vignetting)
        self.say(f"vignetting: corner gain {notes['corner_gain']}{'' if vignetting else ' (not kept)'}")

    def deterministic(self, *, optics_only: bool = False, **replaced: Effect | None) -> list[Effect]:
        """The chain's deterministic centre without its codec (what the set statistics of colour, tone and
        vignetting see), or only its optics stages."""
        chain = [effect.without_randomness() for effect in self.chain(jpeg=None, **replaced)]
        return [effect for effect in chain if effect is not None and (effect.stage == "optics" or not optics_only)]

    def fit_noise(self) -> None:
        if not self.wants(Noise):
            return

        def simulate(noise: Noise | None) -> list[Tensor]:
            return self.simulate(self.chain(noise=noise), self.noise_crops, "unpaired-noise")

        direct = self.cleans is None and not self.stages_after(Noise)
        noise, notes = fit_noise_unpaired(self.real_noise, simulate, direct=direct)
        self.notes[Noise.name] = notes
        self.stages.pop(Noise.name, None)
        if noise is not None:
            self.keep(noise)
        self.say(f"noise: {notes['std_mid_grey_levels']} levels at mid-grey{'' if noise else ' (not kept)'}")

    def refit_noise(self) -> None:
        """The noise again once a detail response is kept: the response shapes the noise before it, as the camera's
        does, and the stage was calibrated without it."""
        if self.stages.get(FrequencyResponse.name) is not None:
            self.fit_noise()

    def fit_transfer(self) -> None:
        if not self.wants(Blur, Sharpen):
            return
        if self.cleans is None:
            self._skip([Blur, Sharpen], "needs a clean set (--clean)")
            return
        use_blur, use_sharpen = self.wants(Blur), self.wants(Sharpen)

        def simulate(sigma: float, amount: float) -> list[Tensor]:
            blur = Blur(sigma) if sigma > 0 and use_blur else None
            sharpen = Sharpen(SHARPEN_SIGMA, amount) if amount > 0 and use_sharpen else None
            return self.simulate(self.chain(blur=blur, sharpen=sharpen), self.spectrum_crops, "unpaired-spectrum")

        (sigma, amount), notes = fit_transfer(self.real_spectrum, simulate)
        self.notes["transfer"] = notes
        for kind in (Blur, Sharpen):
            self.stages.pop(kind.name, None)
        if sigma > 0 and use_blur:
            self.keep(Blur(sigma))
        if amount > 0 and use_sharpen:
            self.keep(Sharpen(SHARPEN_SIGMA, amount))
        self.say(f"blur and sharpening: sigma {sigma} px, amount {amount} (spectrum mismatch {notes})")

    def fit_response(self) -> None:
        """The radial detail response (:meth:`~camdegrade.effects.FrequencyResponse.from_radial`) that takes the
        simulated clean set's mean spectrum to the captures' after every other stage
        (:func:`~camdegrade.fitting._distribution_match.fit_detail_response`, where the rule that keeps it is). On
        City100 (captures 036–055, clean 001–035) blur and sharpening leave 0.147, the response 0.001 (its halves:
        0.168 → 0.020, 0.135 → 0.009), and on the 16 held-out pairs the 0.16–0.25 cycles/pixel band goes from
        +0.51 to +0.09 log2 (``examples/fit_city100_unpaired.py``)."""
        if not self.wants(FrequencyResponse):
            return
        if self.cleans is None:
            self._skip([FrequencyResponse], "needs a clean set (--clean)")
            return
        self.stages.pop(FrequencyResponse.name, None)

        def spectrum(gains: Tensor | None, part: slice) -> Tensor:
            chain = self.chain(frequency_response=None if gains is None else _radial_response(gains))
            return mean_spectrum(self.simulate(chain, self.spectrum_crops[part], "unpaired-response"))

        gains, self.notes[FrequencyResponse.name] = fit_detail_response(self.real_spectra, spectrum)
        if gains is not None:
            self.keep(_radial_response(gains))
        self.say(f"detail response: {self.notes[FrequencyResponse.name]}")

    # -- the record ------------------------------------------------------------------------------------------------

    def fidelity(self, profile: CameraProfile | None = None) -> dict[str, Any]:
        """The simulated clean set (through ``profile``, or the fitted chain) against the captures: flat-noise ratio
        (pooled std), the set means' log2 band power differences
        (:data:`~camdegrade.measures.fidelity.BAND_EDGES`) and the spectrum mismatch."""
        chain = self.chain() if profile is None else profile
        noisy = flat_sums(self.simulate(chain, self.noise_crops, "unpaired-check"))
        real_std = self.real_noise.pooled_std()
        ratio = noisy.pooled_std() / real_std if real_std > 0 else math.nan
        sims = self.simulate(chain, self.spectrum_crops, "unpaired-check")
        sim_bands = torch.stack([band_power(image)[0] for image in sims]).clamp_min(1e-8).log2().mean(0)
        real_crops = [centre_crop(image, SPECTRUM_SIDE) for image in self.captures.images]
        real_bands = torch.stack([band_power(image)[0] for image in real_crops]).clamp_min(1e-8).log2().mean(0)
        mismatch = float((mean_spectrum(sims) - self.real_spectrum).pow(2).mean())
        return {
            "noise_ratio": round(ratio, 3) if math.isfinite(ratio) else None,
            "bands": [round(float(value), 3) for value in sim_bands - real_bands],
            "band_edges": list(BAND_EDGES),
            "spectrum_mismatch": round(mismatch, 4),
        }

    def record(self, seconds: float) -> dict[str, Any]:
        versions = running_versions()
        skipped = self.captures.skipped + (self.cleans.skipped if self.cleans else [])
        out = {
            "unpaired": True,
            "captures": len(self.captures.images),
            "clean_images": len(self.cleans.images) if self.cleans else 0,
            "unreadable": skipped,
            "effects": self.notes,
            "kept": [effect.name for effect in self.chain()],
            "not_fitted": self.not_fitted,
            "not_identifiable": sorted(NOT_IDENTIFIABLE),
            "seed": self.seed,
            "fit_minutes": round(seconds / 60, 2),
            "machine": f"{platform.machine()}, {torch.get_num_threads()} threads, torch {torch.__version__}",
            "camdegrade": __version__,
            "torch": versions["torch"] or str(torch.__version__),
            "torchvision": versions["torchvision"],
        }
        if self.warnings:
            out["warnings"] = list(self.warnings)
        return out
