"""Whether the camera's tone curve is local: the fitted curve applied to a smooth base layer, the detail above it at
one gain (:class:`~camdegrade.effects.Tone`'s ``base_sigma``), where the captures' fine detail depends on the local
brightness as such a curve's does and not as a global one's.

A global curve multiplies fine detail by its slope at each pixel's brightness, so a scene's band power above a few
pixels' period follows how bright it is (City100's unpaired profile, gamma about 1.2: +0.46 log2 in the 0.25–0.35
band on the clean set, +0.68 on held-out scenes, docs/results.md, "The top bands"); a phone that tone-maps locally
leaves the detail at one gain. The statistic is the captures' detail power per band of base brightness
(:func:`detail_by_brightness`), against the simulated clean set's: its log ratio, less its mean (the overall gain
the detail response sets afterwards), is the *tilt* (:func:`tilt`). Each candidate's curve is fitted between the
two sets' base layers (:func:`base_curves`). The two sets' scenes differ, so a candidate replaces the global curve
only where it lowers the tilt by more than a floor and :data:`~camdegrade.fitting.unpaired.judges.SIGNIFICANCE`
standard errors of random half-splits of both sets. On City100's split it does not (docs/results.md, "A local tone
curve and the flat noise"): the captures' detail by brightness is closer to the global curve's there.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar

import torch
from torch import Tensor

from camdegrade.effects import Effect, Tone
from camdegrade.fitting.unpaired.bench import UnpairedFit, UnpairedStep
from camdegrade.fitting.unpaired.judges import SIGNIFICANCE, split_half_error
from camdegrade.fitting.unpaired.steps.color_tone import channel_quantiles, color_tone_estimate, pixel_sample
from camdegrade.fitting.unpaired.steps.spectrum import SPECTRUM_SIDE, centre_crop
from camdegrade.functional import blur_image, blur_planes
from camdegrade.functional.analysis.images import luma

__all__ = [
    "BASE_SIGMAS",
    "BRIGHTNESS_EDGES",
    "TILT_FLOOR",
    "LocalToneMatch",
    "base_curves",
    "detail_by_brightness",
    "local_tone",
    "tilt",
]

#: The base layers tried (Gaussian sigma, px).
BASE_SIGMAS = (2.0, 4.0, 8.0)
#: Brightness bands (of the image's luma smoothed by :data:`BAND_SIGMA`) the detail power is read in ...
BRIGHTNESS_EDGES = (0.0, 0.15, 0.3, 0.45, 0.6, 0.75, 1.0)
BAND_SIGMA = 6.0
#: ... the detail: the luma less its Gaussian of this sigma (px; periods below about 6 px), away from the border ...
DETAIL_SIGMA = 1.5
MARGIN = 16
#: ... and a band is compared where both sides hold this many pixels.
MIN_BAND_PIXELS = 20_000
#: A local curve is kept where it lowers the tilt (log2) by more than this.
TILT_FLOOR = 0.05


def detail_by_brightness(image: Tensor) -> Tensor:
    """``(2, bands)``: the sum of the squared detail (luma less its Gaussian of :data:`DETAIL_SIGMA`) and the pixel
    count in each band of :data:`BRIGHTNESS_EDGES` of the luma smoothed by :data:`BAND_SIGMA` (the band power a
    spectrum reads, by brightness; sums add up over images)."""
    plane = luma(image[None]).reshape(1, *image.shape[-2:])
    detail = (plane - blur_planes(plane, DETAIL_SIGMA))[0, MARGIN:-MARGIN, MARGIN:-MARGIN].double().reshape(-1)
    base = blur_planes(plane, BAND_SIGMA)[0, MARGIN:-MARGIN, MARGIN:-MARGIN].double().reshape(-1)
    band = torch.bucketize(base, torch.tensor(BRIGHTNESS_EDGES[1:-1], dtype=torch.float64))
    bands = len(BRIGHTNESS_EDGES) - 1
    return torch.stack([torch.bincount(band, detail.pow(2), bands), torch.bincount(band, minlength=bands).double()])


def tilt(simulated: Tensor, captured: Tensor) -> Tensor:
    """The RMS over brightness bands (weighted by the fewer pixels of the two sides) of the log2 detail power of
    ``simulated`` over ``captured`` (:func:`detail_by_brightness` sums), less its weighted mean; NaN (not
    measurable) where fewer than two bands hold :data:`MIN_BAND_PIXELS` pixels on both sides."""
    used = (simulated[1] >= MIN_BAND_PIXELS) & (captured[1] >= MIN_BAND_PIXELS)
    if int(used.sum()) < 2:
        return torch.full((), math.nan, dtype=torch.float64)
    power = [(sums[0] / sums[1])[used].clamp_min(1e-30) for sums in (simulated, captured)]
    ratio = (power[0] / power[1]).log2()
    weight = torch.minimum(simulated[1], captured[1])[used]
    mean = (weight * ratio).sum() / weight.sum()
    return ((weight * (ratio - mean).pow(2)).sum() / weight.sum()).sqrt()


def local_tone(tone: Tone, sigma: float, *, exposure_jitter: float | None = None) -> Tone:
    """``tone``'s curve on a base layer of ``sigma`` px (0: the global curve), with its exposure jitter or
    ``exposure_jitter``."""
    values = (float(getattr(tone, key)) for key in ("gamma", "black", "white", "exposure"))
    jitter = tone.exposure_jitter if exposure_jitter is None else exposure_jitter
    return Tone(*values, exposure_jitter=jitter, base_sigma=sigma)


def base_curves(fit: UnpairedFit) -> dict[float, Tone]:
    """A local curve for each of :data:`BASE_SIGMAS`, its levels and gamma fitted as the global curve's are
    (:func:`~camdegrade.fitting.unpaired.steps.color_tone.color_tone_estimate`, the kept white balance applied) but
    between the two sets' base layers: a local curve maps the base, and the detail it carries at one gain widens
    the captures' quantiles, which a curve fitted on the whole pixels reads as more contrast."""
    sources = fit.simulate(fit.deterministic(tone=None), fit.cleans.images, "unpaired-deterministic")
    tone = fit.stages[Tone.name]
    out = {}
    for sigma in BASE_SIGMAS:
        real, clean = (
            channel_quantiles([pixel_sample(blur_image(image, sigma)) for image in images])
            for images in (fit.captures.images, sources)
        )
        curve = color_tone_estimate(real, clean, gains=False)[1]
        out[sigma] = local_tone(curve, sigma, exposure_jitter=tone.exposure_jitter)
    return out


@dataclass(frozen=True)
class LocalToneProposal:
    """Per image :func:`detail_by_brightness` sums: the captures' ``(C, 2, bands)`` and the simulated clean set's
    for each base sigma tried (0: the global curve) ``{sigma: (K, 2, bands)}``."""

    captured: Tensor
    simulated: dict[float, Tensor]
    tones: dict[float, Tone]

    def tilts(self, captures: Sequence[int], cleans: Sequence[int]) -> Tensor:
        """The :func:`tilt` of each sigma (in the dict's order) on these images."""
        real = self.captured[list(captures)].sum(0)
        return torch.stack([tilt(sums[list(cleans)].sum(0), real) for sums in self.simulated.values()])


@dataclass(frozen=True)
class LocalToneMatch(UnpairedStep):
    """The local tone step (it needs the clean set and a kept tone curve): the curve on a base layer of each of
    :data:`BASE_SIGMAS`, the one with the smallest tilt kept where it beats the global curve's (see the module)."""

    name: ClassVar[str] = "local_tone"
    kinds: ClassVar[tuple[type[Effect], ...]] = (Tone,)
    needs_clean: ClassVar[bool] = True

    def applies(self, fit: UnpairedFit) -> bool:
        return fit.stages.get(Tone.name) is not None

    def propose(self, fit: UnpairedFit) -> LocalToneProposal:
        tones = {0.0: fit.stages[Tone.name], **base_curves(fit)}
        captured = torch.stack(
            [detail_by_brightness(centre_crop(image, SPECTRUM_SIDE)) for image in fit.captures.images]
        )
        simulated = {}
        for sigma, tone in tones.items():
            images = fit.simulate(fit.chain(tone=tone), fit.sets.spectrum_crops, "unpaired-tone")
            simulated[sigma] = torch.stack([detail_by_brightness(image) for image in images])
        return LocalToneProposal(captured, simulated, tones)

    def judge(self, fit: UnpairedFit, proposal: LocalToneProposal) -> dict:
        captures, cleans = len(proposal.captured), len(next(iter(proposal.simulated.values())))
        tilts = proposal.tilts(range(captures), range(cleans))
        sigmas = list(proposal.simulated)
        best = 1 + int(tilts[1:].nan_to_num(math.inf).argmin())

        def gain(real: list[int], clean: list[int]) -> Tensor:
            each = proposal.tilts(real, clean)
            return each[0] - each[best]

        error = float(split_half_error(gain, captures, cleans, fit.seed))
        lowered = float(tilts[0] - tilts[best])
        # a half too small to read the tilt on leaves the error NaN: then nothing says the gain is not the content's
        measurable = math.isfinite(error) and math.isfinite(lowered)
        kept = measurable and lowered > max(TILT_FLOOR, SIGNIFICANCE * error)
        if kept:
            fit.keep(proposal.tones[sigmas[best]], Tone)
        notes = {
            "tilts": {f"{sigma:g}": _rounded(float(value)) for sigma, value in zip(sigmas, tilts, strict=True)},
            "base_sigma": sigmas[best] if kept else 0.0,
            "lowered": _rounded(lowered),
            "error": _rounded(error),
            "kept": kept,
            **({} if measurable else {"reason": "the tilt is not measurable on half of the sets"}),
        }
        fit.say(f"local tone: {notes}")
        return notes


def _rounded(value: float) -> float | None:
    return round(value, 4) if math.isfinite(value) else None
