"""Effect stages estimated by matching the distribution of a camera's photos to that of a clean set of *other*
scenes (no correspondence): colour and tone by quantile matching, vignetting from the normalised radial mean, the
transfer function (blur, sharpening, then a radial detail response for what those two leave) from radial power
spectra, JPEG quality from the files' quantisation tables (:mod:`camdegrade.fitting._unpaired_jpeg` reads them).

Each estimator compares set statistics, so content differences between the two sets average out only over many
images; each keeps its stage only when it moves its statistic by more than a stated floor (below which the
difference is the content's). Noise has its own module (:mod:`camdegrade.fitting._unpaired_noise`).
"""

from __future__ import annotations

import io
import math
from collections.abc import Callable, Sequence
from functools import lru_cache

import torch
from torch import Tensor

from camdegrade._seeds import derived_generator
from camdegrade.effects import Color, FrequencyResponse, Tone, Vignetting
from camdegrade.effects._fitting import downscale, minimize
from camdegrade.functional import linear_to_srgb, relative_radius, srgb_to_linear
from camdegrade.functional.analysis import hann2d, luma
from camdegrade.functional.tone import tone_curve

#: Quantiles of each channel compared (1-D optimal transport between two sets is the map between their quantiles).
QUANTILES = torch.linspace(0.01, 0.99, 99, dtype=torch.float64)
#: At most this many pixels of each image enter the quantiles (evenly strided).
PIXELS_PER_IMAGE = 20_000
#: A white-balance gain is kept when some channel's differs from 1 by more than this (log units, about 3 %) ...
COLOR_FLOOR = 0.03
#: ... a tone curve when it moves some value by more than this (about 5 8-bit levels) ...
TONE_FLOOR = 0.02
#: ... vignetting when the corner gain differs from 1 by more than this.
VIGNETTING_FLOOR = 0.04
#: Rings of relative radius of the vignetting profile, and the side the images are averaged down to first.
RINGS = 8
RING_SIDE = 128
#: Radial frequency bands (cycles/pixel, geometric) of the spectrum match; the first ``REFERENCE_BANDS`` (up to
#: about 0.06) are the reference that takes out each image's contrast.
SPECTRUM_EDGES = tuple(float(v) for v in torch.logspace(math.log10(0.02), math.log10(0.5), 13))
REFERENCE_BANDS = 4
SPECTRUM_SIDE = 512
#: Candidate PSFs (Gaussian sigma, px) and sharpening amounts (unsharp mask, sigma :data:`SHARPEN_SIGMA`).
BLUR_SIGMAS = (0.0, 0.4, 0.6, 0.8, 1.0, 1.25, 1.5, 1.75, 2.0, 2.5, 3.0)
SHARPEN_AMOUNTS = (0.0, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0)
SHARPEN_SIGMA = 1.0
#: The grid's best is then tried this far either way in sigma and in amount.
REFINE = 0.125
#: A transfer function is kept when it lowers the spectrum mismatch below this share of the identity's, and the
#: identity's mismatch is above :data:`SPECTRUM_FLOOR` (mean squared log2 power per band).
SPECTRUM_GAIN = 0.5
SPECTRUM_FLOOR = 0.01
#: The detail response (:func:`fit_detail_response`): correction rounds (each moves every band's amplitude gain by
#: half its log2 power error; on City100's sets the mismatch goes 0.147 → 0.017 → 0.003 → 0.001, recorded in the
#: profile as ``rounds``); the most one round moves a band's log2 gain (a factor 2 in amplitude: City100's largest
#: first step is 0.30) and the most any gain may reach (the stage's range, ``FrequencyResponse.MAX_GAIN``).
RESPONSE_ROUNDS = 3
RESPONSE_STEP = 1.0
RESPONSE_LIMIT = math.log2(FrequencyResponse.MAX_GAIN)
#: ... fitted only where every other stage leaves more mismatch than this. A systematic difference passes the
#: halves' check as well as a camera's: an earlier stage's misfit the same in both halves, or texture the capture
#: scenes have and the clean ones lack. On simulated cameras with no detail response such differences left 0.029–
#: 0.032 and a response kept there made new scenes' bands 0.1–0.2 log2 worse (``tests/test_unpaired_fit.py``);
#: City100's iPhone leaves 0.147, the test suite's detail camera 0.21.
RESPONSE_FLOOR = 0.06


# -- colour and tone ---------------------------------------------------------------------------------------------


def pixel_sample(image: Tensor) -> Tensor:
    """``(3, P)``: at most :data:`PIXELS_PER_IMAGE` of the image's pixels (evenly strided), in linear light."""
    flat = image.reshape(3, -1)
    return srgb_to_linear(flat[:, :: max(1, flat.shape[1] // PIXELS_PER_IMAGE)].double())


def channel_quantiles(samples: Sequence[Tensor]) -> Tensor:
    """``(3, len(QUANTILES))`` quantiles of each channel of the pooled :func:`pixel_sample` s."""
    return torch.quantile(torch.cat(list(samples), 1), QUANTILES, dim=1).T


def split_half_error(
    estimate: Callable[[list[int], list[int]], Tensor], captures: int, cleans: int, seed: int
) -> Tensor:
    """The standard error of ``estimate(capture indices, clean indices)`` over the whole sets, from
    :data:`SPLITS` random half-splits of both: RMS of half the difference of the two halves' estimates (each half
    has twice the full set's variance). What the content of the images alone moves the estimate by."""
    generator = derived_generator(seed, "unpaired-split")
    halves = []
    for _ in range(SPLITS):
        a, b = (
            torch.randperm(captures, generator=generator).tolist(),
            torch.randperm(cleans, generator=generator).tolist(),
        )
        first = estimate(a[: captures // 2], b[: cleans // 2])
        second = estimate(a[captures // 2 :], b[cleans // 2 :])
        halves.append((first - second) / 2)
    return torch.stack(halves).pow(2).mean(0).sqrt()


def significant(change: Tensor, error: Tensor, floor: float) -> bool:
    """Whether some component of ``change`` exceeds both ``floor`` and :data:`SIGNIFICANCE` standard errors."""
    return bool((change.abs() > torch.clamp(SIGNIFICANCE * error, min=floor)).any())


#: Random half-splits behind a standard error, and how many of them a kept change must exceed.
SPLITS = 8
SIGNIFICANCE = 3.0
#: The values at which a tone curve's change is tested.
TONE_GRID = torch.linspace(0.1, 0.9, 9, dtype=torch.float64)


def color_tone_estimate(real: Tensor, clean: Tensor) -> tuple[Tensor, Tone]:
    """White-balance gains ``(3,)`` and a tone curve mapping the quantiles ``clean`` onto ``real`` (both
    :func:`channel_quantiles`), fitted together by L-BFGS (see :func:`fit_color_tone`)."""
    target = linear_to_srgb(real.clamp(0, 1))
    weight = (((QUANTILES >= 0.02) & (QUANTILES <= 0.98))[None] & (real < 0.99) & (real > 1e-4)).double()
    log_gains = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    log_gamma, black, log_range = (torch.zeros((), dtype=torch.float64, requires_grad=True) for _ in range(3))
    zero = torch.zeros((), dtype=torch.float64)

    def balanced() -> Tensor:  # an overall gain is the curve's levels' to say: the gains' geometric mean is 1
        return (log_gains - log_gains.mean()).exp()

    def loss() -> Tensor:
        source = linear_to_srgb((clean * balanced()[:, None]).clamp(0, 1))
        predicted = tone_curve(source, log_gamma.exp(), black, black + log_range.exp(), zero)
        return (weight * (predicted - target).pow(2)).sum() / weight.sum()

    minimize([log_gains, log_gamma, black, log_range], loss, max_iter=200)
    with torch.no_grad():
        tone = Tone(float(log_gamma.exp()), float(black), float(black + log_range.exp()))
        return balanced().clamp(0.05, 16.0).detach(), tone


def fit_color_tone(
    captures: Sequence[Tensor], cleans: Sequence[Tensor], seed: int = 0, *, test: bool = True
) -> tuple[Color | None, Tone | None, dict]:
    """White-balance gains and a tone curve that map the clean set's channel quantiles onto the captures'.

    The gains (a diagonal :class:`~camdegrade.effects.Color`, linear light) and the
    :class:`~camdegrade.effects.Tone` curve (one for the three channels) are fitted together: least squares between
    the sRGB quantiles 0.02–0.98 of the captures and those of the clean set through gains and curve. An overall
    gain and the curve's levels trade against each other, so the gains are a white balance (their geometric mean
    is 1) and the curve carries the exposure. Each
    is kept where it changes something by more than its floor (:data:`COLOR_FLOOR`, :data:`TONE_FLOOR`) and by
    more than :data:`SIGNIFICANCE` standard errors of the content (:func:`split_half_error`; ``test=False``: by
    its floor alone, for an intermediate round).

    References:
        G. Peyré, M. Cuturi, "Computational Optimal Transport", Foundations and Trends in Machine Learning 11, 2019
        (§2.6: in one dimension the optimal map sends each quantile to the same quantile).
    """
    real_samples, clean_samples = [pixel_sample(image) for image in captures], [pixel_sample(image) for image in cleans]

    def estimate(real_indices: list[int], clean_indices: list[int]) -> Tensor:
        real = channel_quantiles([real_samples[i] for i in real_indices])
        clean = channel_quantiles([clean_samples[i] for i in clean_indices])
        gains, tone = color_tone_estimate(real, clean)
        return torch.cat([gains.log(), _curve(tone, TONE_GRID) - TONE_GRID])

    change = estimate(list(range(len(captures))), list(range(len(cleans))))
    no_test = torch.zeros_like(change)
    error = split_half_error(estimate, len(captures), len(cleans), seed) if test else no_test
    color_kept = significant(change[:3], error[:3], COLOR_FLOOR)
    real, clean = channel_quantiles(real_samples), channel_quantiles(clean_samples)
    gains, tone = color_tone_estimate(real, clean)
    if not color_kept:
        gains, tone = torch.ones(3, dtype=torch.float64), _tone_between(clean, linear_to_srgb(real.clamp(0, 1)))
    tone_change = _curve(tone, TONE_GRID) - TONE_GRID
    tone_kept = significant(tone_change, error[3:], TONE_FLOOR)
    notes = {
        "gains": [round(float(g), 4) for g in change[:3].exp()],
        "gains_error": [round(float(e), 4) for e in error[:3]],
        "tone_change": [round(float(v), 4) for v in tone_change],
        "tone_error": [round(float(e), 4) for e in error[3:]],
    }
    color = Color(torch.diag(gains).float()) if color_kept else None
    return color, tone if tone_kept else None, notes


def _tone_between(clean: Tensor, target: Tensor) -> Tone:
    """The tone curve alone from the clean quantiles (linear) to the captures' (sRGB)."""
    source = linear_to_srgb(clean.clamp(0, 1))
    return Tone.fit(source[:, None, :].float(), target[:, None, :].float())


def _curve(tone: Tone, values: Tensor) -> Tensor:
    return tone_curve(values, *(getattr(tone, key).double() for key in ("gamma", "black", "white", "exposure")))


# -- vignetting ----------------------------------------------------------------------------------------------------


def ring_profile(image: Tensor) -> Tensor:
    """``(RINGS,)`` log mean linear luma per ring of relative radius, less the central ring's (vignetting's trace)."""
    small = luma(downscale(srgb_to_linear(image.double()), RING_SIDE))
    radius = relative_radius(*small.shape, torch.float64, small.device)
    rings = (radius * RINGS).long().clamp(max=RINGS - 1).flatten()
    means = torch.bincount(rings, small.flatten(), RINGS) / torch.bincount(rings, minlength=RINGS).clamp_min(1)
    return means.clamp_min(1e-4).log() - means[0].clamp_min(1e-4).log()


def ring_profiles(images: Sequence[Tensor]) -> Tensor:
    """``(N, RINGS)``: :func:`ring_profile` of each image."""
    return torch.stack([ring_profile(image) for image in images])


def _ring_moments(height: int, width: int) -> tuple[Tensor, Tensor]:
    """Mean ``r²`` and ``r⁴`` per ring of a frame of this shape (averaged down as :func:`ring_profile` does)."""
    factor = max(height, width) / RING_SIDE
    if factor > 1:
        height, width = max(1, round(height / factor)), max(1, round(width / factor))
    radius = relative_radius(height, width, torch.float64, torch.device("cpu")).flatten()
    rings = (radius * RINGS).long().clamp(max=RINGS - 1)
    count = torch.bincount(rings, minlength=RINGS).clamp_min(1)
    return (torch.bincount(rings, radius**2, RINGS) / count, torch.bincount(rings, radius**4, RINGS) / count)


def vignetting_step(difference: Tensor, shape: tuple[int, int]) -> tuple[float, float]:
    """``(k1, k2)`` of the gain ``1 + k1 r² + k2 r⁴`` whose ring means, relative to the centre's, are
    ``exp(difference)`` (linear least squares after multiplying out the centre's gain)."""
    r2, r4 = _ring_moments(*shape)
    ratio = difference.exp()
    design = torch.stack([r2 - ratio * r2[0], r4 - ratio * r4[0]], 1)
    solution = torch.linalg.lstsq(design, (ratio - 1)[:, None]).solution[:, 0]
    return float(solution[0]), float(solution[1])


def fit_vignetting(
    real: Tensor,
    reference: Tensor,
    shape: tuple[int, int],
    simulate: Callable[[Vignetting], Tensor] | None,
    seed: int = 0,
) -> tuple[Vignetting | None, dict]:
    """Vignetting from the captures' mean ring profile (``real``, :func:`ring_profiles` ``(N, RINGS)``) over
    ``reference``'s (the clean set's ``(M, RINGS)``; a flat field where it has no rows), then, with ``simulate``,
    one round of simulated moments: the clean set's ring profiles through the chain with that vignetting against
    the captures' (a tone curve after the optics bends the falloff). Kept where the corner gain differs from 1 by
    more than :data:`VIGNETTING_FLOOR` and :data:`SIGNIFICANCE` standard errors of the content.

    References:
        D. B. Goldman, "Vignette and exposure calibration and compensation", IEEE TPAMI 32(12), 2010 (the radial
        falloff read from the statistics of many frames).
    """

    def corner(real_indices: list[int], clean_indices: list[int]) -> Tensor:
        base = reference[clean_indices].mean(0) if len(reference) else torch.zeros(RINGS, dtype=torch.float64)
        k1, k2 = vignetting_step(real[real_indices].mean(0) - base, shape)
        return torch.tensor([k1 + k2], dtype=torch.float64)

    base = reference.mean(0) if len(reference) else torch.zeros(RINGS, dtype=torch.float64)
    k1, k2 = vignetting_step(real.mean(0) - base, shape)
    if simulate is not None:
        d1, d2 = vignetting_step(real.mean(0) - simulate(Vignetting(k1, k2)).mean(0), shape)
        k1, k2 = k1 + d1, k2 + d2
    k1, k2 = max(-10.0, min(10.0, k1)), max(-10.0, min(10.0, k2))
    error = split_half_error(corner, len(real), max(len(reference), 1), seed)
    kept = significant(torch.tensor([k1 + k2]), error, VIGNETTING_FLOOR)
    notes = {
        "k1": round(k1, 4),
        "k2": round(k2, 4),
        "corner_gain": round(1 + k1 + k2, 4),
        "error": round(float(error), 4),
    }
    return (Vignetting(k1, k2) if kept else None), notes


# -- transfer function ---------------------------------------------------------------------------------------------


def centre_crop(image: Tensor, side: int) -> Tensor:
    height, width = image.shape[-2:]
    h, w = min(side, height), min(side, width)
    top, left = (height - h) // 2, (width - w) // 2
    return image[..., top : top + h, left : left + w]


def log_spectrum(image: Tensor) -> Tensor:
    """Log2 mean luma power (Hann window) per band of :data:`SPECTRUM_EDGES` above the first
    :data:`REFERENCE_BANDS`, less their mean (the image's own contrast taken out)."""
    gray = luma(image.double()) * 255.0
    height, width = gray.shape
    power = torch.fft.rfft2((gray - gray.mean()) * hann2d(height, width, torch.float64)).abs().pow(2)
    radius = torch.sqrt(torch.fft.fftfreq(height)[:, None] ** 2 + torch.fft.rfftfreq(width)[None, :] ** 2).double()
    band = torch.bucketize(radius, torch.tensor(SPECTRUM_EDGES, dtype=torch.float64), right=True) - 1
    inside = (band >= 0) & (band < len(SPECTRUM_EDGES) - 1)
    bands = len(SPECTRUM_EDGES) - 1
    sums = torch.bincount(band[inside], power[inside], bands) / torch.bincount(band[inside], minlength=bands).clamp(1)
    logs = sums.clamp_min(1e-12).log2()
    return logs[REFERENCE_BANDS:] - logs[:REFERENCE_BANDS].mean()


def mean_spectrum(images: Sequence[Tensor]) -> Tensor:
    return torch.stack([log_spectrum(centre_crop(image, SPECTRUM_SIDE)) for image in images]).mean(0)


def fit_transfer(real: Tensor, simulate: Callable[[float, float], list[Tensor]]) -> tuple[tuple[float, float], dict]:
    """``(blur sigma, sharpen amount)`` of the grid whose simulated set's mean spectrum (:func:`mean_spectrum`,
    noise and codec included, so the noise floor is matched rather than read as sharpness) is closest to the
    captures' ``real``; ``(0, 0)`` unless it is clearly better than the identity (:data:`SPECTRUM_GAIN`).

    References:
        A. Levin, Y. Weiss, F. Durand, W. T. Freeman, "Understanding and evaluating blind deconvolution
        algorithms", CVPR 2009 (a PSF read from the power spectrum against natural-image statistics).
    """
    losses: dict[tuple[float, float], float] = {}

    def at(sigma: float, amount: float) -> None:
        if (sigma, amount) not in losses:
            losses[(sigma, amount)] = float((mean_spectrum(simulate(sigma, amount)) - real).pow(2).mean())

    for sigma in BLUR_SIGMAS:  # each alone, then each beside the other's best
        at(sigma, 0.0)
    for amount in SHARPEN_AMOUNTS:
        at(0.0, amount)
    best_sigma = min(BLUR_SIGMAS, key=lambda sigma: losses[(sigma, 0.0)])
    best_amount = min(SHARPEN_AMOUNTS, key=lambda amount: losses[(0.0, amount)])
    for amount in SHARPEN_AMOUNTS:
        at(best_sigma, amount)
    for sigma in BLUR_SIGMAS:
        at(sigma, best_amount)
    sigma, amount = min(losses, key=losses.__getitem__)
    for step in (-REFINE, REFINE):  # halfway to the grid's neighbours
        at(max(sigma + step, 0.0), amount)
        at(sigma, max(amount + step, 0.0))
    identity = losses[(0.0, 0.0)]
    best = min(losses, key=losses.__getitem__)
    kept = identity > SPECTRUM_FLOOR and losses[best] < SPECTRUM_GAIN * identity
    chosen = best if kept else (0.0, 0.0)
    notes = {"identity_mismatch": round(identity, 4), "best_mismatch": round(losses[best], 4), "best": list(best)}
    return chosen, notes


def band_centres() -> Tensor:
    """The geometric centres (cycles/pixel) of the last reference band and of every band :func:`log_spectrum`
    reports: where :func:`fit_band_gains`' gains sit, the first held at 1 (the reference carries no gain)."""
    edges = torch.tensor(SPECTRUM_EDGES, dtype=torch.float64)
    return (edges[REFERENCE_BANDS - 1 : -1] * edges[REFERENCE_BANDS:]).sqrt()


def fit_band_gains(
    real: Tensor, simulate: Callable[[Tensor], Tensor], rounds: int = RESPONSE_ROUNDS
) -> tuple[Tensor, list[float]]:
    """Log2 amplitude gains per band of :func:`log_spectrum` whose response, applied by ``simulate(gains)`` (the
    simulated set's mean spectrum), gives the captures' mean spectrum ``real``; and the mismatch before each round.
    Each round moves every band's gain by half its log2 power error (power is amplitude squared), at most
    :data:`RESPONSE_STEP`, within ±:data:`RESPONSE_LIMIT`.

    References:
        D. J. Heeger, J. R. Bergen, "Pyramid-based texture analysis/synthesis", SIGGRAPH 1995 (a texture's
        subband statistics matched by iterating on the synthesis).
    """
    gains, mismatches = torch.zeros_like(real), []
    for _ in range(rounds):
        error = simulate(gains) - real
        mismatches.append(float(error.pow(2).mean()))
        step = (error / 2).clamp(-RESPONSE_STEP, RESPONSE_STEP)
        gains = (gains - step).clamp(-RESPONSE_LIMIT, RESPONSE_LIMIT)
    return gains, mismatches


SimulateParts = Callable[[Tensor | None, slice], Tensor]


def fit_detail_response(real_spectra: Tensor, simulate: SimulateParts) -> tuple[Tensor | None, dict]:
    """The log2 band gains (:func:`fit_band_gains`) of a detail response after the rest of the chain, or ``None``
    where it is not kept; and notes for the metadata.

    ``real_spectra`` is ``(N, bands)``, the captures' :func:`log_spectrum` each; ``simulate(gains, part)`` the mean
    spectrum of the ``part`` slice of the simulated clean set (``gains`` ``None``: without a response). Kept where
    the mismatch left is above :data:`RESPONSE_FLOOR` (and :data:`SPECTRUM_FLOOR`) and gains fitted on either half
    of both sets take the *other* half's mismatch below :data:`SPECTRUM_GAIN` of what it was: a difference between
    random halves of the scenes does not carry over. A difference the two sets have throughout does, hence the floor.
    """
    everything, halves = slice(None), (slice(0, None, 2), slice(1, None, 2))

    def mismatch(gains: Tensor | None, part: slice) -> float:
        return float((simulate(gains, part) - real_spectra[part].mean(0)).pow(2).mean())

    left = mismatch(None, everything)
    checks = []
    if left > max(RESPONSE_FLOOR, SPECTRUM_FLOOR):
        for fitted_on, checked_on in (halves, halves[::-1]):
            gains, _ = fit_band_gains(real_spectra[fitted_on].mean(0), lambda g, part=fitted_on: simulate(g, part))
            checks.append((mismatch(None, checked_on), mismatch(gains, checked_on)))
    kept = bool(checks) and all(after < SPECTRUM_GAIN * before for before, after in checks)
    notes: dict = {
        "mismatch_left": round(left, 4),
        "halves": [[round(before, 4), round(after, 4)] for before, after in checks],
        "kept": kept,
    }
    if not kept:
        return None, notes
    gains, rounds = fit_band_gains(real_spectra.mean(0), lambda g: simulate(g, everything))
    notes["band_gains"] = [round(float(value), 3) for value in gains.exp2()]
    notes["rounds"] = [round(value, 4) for value in rounds]
    notes["mismatch"] = round(mismatch(gains, everything), 4)
    return gains, notes


# -- codec ---------------------------------------------------------------------------------------------------------


@lru_cache(maxsize=1)
def standard_tables() -> dict[int, dict[int, tuple[int, ...]]]:
    """Quality → the quantisation tables libjpeg writes at that quality (as PIL reports them)."""
    from PIL import Image

    out = {}
    for quality in range(1, 101):
        buffer = io.BytesIO()
        Image.new("RGB", (8, 8)).save(buffer, "JPEG", quality=quality)
        with Image.open(buffer) as image:
            out[quality] = {key: tuple(table) for key, table in image.quantization.items()}
    return out


def quality_from_tables(tables: dict[int, Sequence[int]]) -> tuple[int, bool]:
    """The libjpeg quality whose tables are nearest (log ratio, summed) to ``tables``, and whether they are equal
    (a camera with tables of its own gets the nearest standard quality)."""

    def distance(quality: int) -> float:
        reference = standard_tables()[quality]
        total = 0.0
        for key, table in tables.items():
            if key in reference and len(table) == len(reference[key]):
                total += sum(abs(math.log(max(a, 1) / max(b, 1))) for a, b in zip(table, reference[key], strict=True))
        return total

    best = min(range(1, 101), key=distance)
    return best, distance(best) == 0.0
