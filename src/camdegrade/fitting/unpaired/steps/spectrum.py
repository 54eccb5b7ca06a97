"""The transfer function from two sets of different scenes: the blur and the sharpening whose simulation of the
clean set has the captures' radial power spectrum, then a radial detail response for what those two leave (a
phone's detail processing has no Gaussian-plus-unsharp shape), kept where a response fitted on each half of the sets
also brings the other half's spectrum closer."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import ClassVar

import torch
from torch import Tensor

from camdegrade.effects import Blur, Effect, FrequencyResponse, Sharpen
from camdegrade.fitting.unpaired.bench import UnpairedFit, UnpairedStep
from camdegrade.fitting.unpaired.steps.edges import (
    EdgeSpread,
    blur_by_edges,
    captures_edge_spread,
    farther,
    rounded,
    sharpens_away,
    simulated_width,
)
from camdegrade.functional.analysis.images import hann2d, luma, radial_frequency

__all__ = [
    "DetailResponseMatch",
    "TransferMatch",
    "fit_detail_response",
    "log_spectrum",
    "mean_spectrum",
    "radial_response",
]

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
#: Knots per axis of the detail response: 0.025 cycles/pixel apart, finer than the narrowest band it is fitted on.
RESPONSE_KNOTS = 21


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
    radius = radial_frequency(height, width).double()
    band = torch.bucketize(radius, torch.tensor(SPECTRUM_EDGES, dtype=torch.float64), right=True) - 1
    inside = (band >= 0) & (band < len(SPECTRUM_EDGES) - 1)
    bands = len(SPECTRUM_EDGES) - 1
    sums = torch.bincount(band[inside], power[inside], bands) / torch.bincount(band[inside], minlength=bands).clamp(1)
    logs = sums.clamp_min(1e-12).log2()
    return logs[REFERENCE_BANDS:] - logs[:REFERENCE_BANDS].mean()


def mean_spectrum(images: Sequence[Tensor]) -> Tensor:
    return torch.stack([log_spectrum(centre_crop(image, SPECTRUM_SIDE)) for image in images]).mean(0)


def transfer_mismatches(
    real: Tensor, simulate: Callable[[float, float], list[Tensor]]
) -> dict[tuple[float, float], float]:
    """The spectrum mismatch (mean squared log2 power per band of :func:`mean_spectrum`, noise and codec included,
    so the noise floor is matched rather than read as sharpness) against the captures' ``real`` of ``simulate(blur
    sigma, sharpen amount)``: each candidate of the grid alone, then each beside the other's best, then halfway to
    the best's neighbours.

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
    return losses


def judge_transfer(losses: dict[tuple[float, float], float]) -> tuple[tuple[float, float], dict]:
    """``(blur sigma, sharpen amount)`` of the least mismatch, or ``(0, 0)`` unless it is clearly better than the
    identity's (:data:`SPECTRUM_GAIN`, above :data:`SPECTRUM_FLOOR`); and the record."""
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
#: The two halves of the sets a detail response is fitted on and checked on (every other image).
HALVES = (slice(0, None, 2), slice(1, None, 2))


@dataclass(frozen=True)
class ResponseProposal:
    """The mismatch every other stage leaves, and the band gains fitted on each half of the sets (none where it is
    below the floor)."""

    left: float
    halves: list[tuple[slice, slice, Tensor]]


def propose_detail_response(real_spectra: Tensor, simulate: SimulateParts) -> ResponseProposal:
    """The log2 band gains (:func:`fit_band_gains`) of a detail response after the rest of the chain, fitted on each
    half of both sets (:data:`HALVES`), where the mismatch left is above :data:`RESPONSE_FLOOR` (and
    :data:`SPECTRUM_FLOOR`).

    ``real_spectra`` is ``(N, bands)``, the captures' :func:`log_spectrum` each; ``simulate(gains, part)`` the mean
    spectrum of the ``part`` slice of the simulated clean set (``gains`` ``None``: without a response).
    """
    left = _mismatch(real_spectra, simulate, None, slice(None))
    halves = []
    if left > max(RESPONSE_FLOOR, SPECTRUM_FLOOR):
        for fitted_on, checked_on in (HALVES, HALVES[::-1]):
            gains, _ = fit_band_gains(real_spectra[fitted_on].mean(0), lambda g, part=fitted_on: simulate(g, part))
            halves.append((fitted_on, checked_on, gains))
    return ResponseProposal(left, halves)


def judge_detail_response(
    real_spectra: Tensor, simulate: SimulateParts, proposal: ResponseProposal
) -> tuple[Tensor | None, dict]:
    """Kept where the gains fitted on either half take the *other* half's mismatch below :data:`SPECTRUM_GAIN` of
    what it was: a difference between random halves of the scenes does not carry over (a difference the two sets
    have throughout does, hence the floor). Then fitted on the whole sets; ``None`` where not kept, and the record."""
    checks = [
        (_mismatch(real_spectra, simulate, None, checked), _mismatch(real_spectra, simulate, gains, checked))
        for _, checked, gains in proposal.halves
    ]
    kept = bool(checks) and all(after < SPECTRUM_GAIN * before for before, after in checks)
    notes: dict = {
        "mismatch_left": round(proposal.left, 4),
        "halves": [[round(before, 4), round(after, 4)] for before, after in checks],
        "kept": kept,
    }
    if not kept:
        return None, notes
    gains, rounds = fit_band_gains(real_spectra.mean(0), lambda g: simulate(g, slice(None)))
    notes["band_gains"] = [round(float(value), 3) for value in gains.exp2()]
    notes["rounds"] = [round(value, 4) for value in rounds]
    notes["mismatch"] = round(_mismatch(real_spectra, simulate, gains, slice(None)), 4)
    return gains, notes


def fit_detail_response(real_spectra: Tensor, simulate: SimulateParts) -> tuple[Tensor | None, dict]:
    """The log2 band gains of a detail response after the rest of the chain, or ``None`` where it is not kept; and
    notes for the metadata (:func:`propose_detail_response`, then :func:`judge_detail_response`)."""
    return judge_detail_response(real_spectra, simulate, propose_detail_response(real_spectra, simulate))


def _mismatch(real_spectra: Tensor, simulate: SimulateParts, gains: Tensor | None, part: slice) -> float:
    return float((simulate(gains, part) - real_spectra[part].mean(0)).pow(2).mean())


def radial_response(log2_gains: Tensor) -> FrequencyResponse:
    """The detail response of amplitude gains ``2 ** log2_gains`` at the bands' centres (1 at the reference's)."""
    gains = [1.0, *log2_gains.exp2().tolist()]
    return FrequencyResponse.from_radial(band_centres().tolist(), gains, knots=RESPONSE_KNOTS)


@dataclass(frozen=True)
class TransferProposal:
    """The spectrum mismatch of each (blur sigma, sharpen amount) tried, the median step width of its simulation,
    the captures' :class:`~camdegrade.fitting.unpaired.steps.edges.EdgeSpread`, and the blur sigma that gives the
    captures' step width (``None`` where it is not measured: the spectrum alone decides)."""

    losses: dict[tuple[float, float], float]
    widths: dict[tuple[float, float], float]
    spread: EdgeSpread
    sigma: float | None


def judge_by_edges(proposal: TransferProposal) -> tuple[tuple[float, float], dict]:
    """Of the (blur, sharpening) pairs tried whose median step width is as close to the captures' as that of the
    blur of :attr:`TransferProposal.sigma` alone, or within the tolerance of it
    (:func:`~camdegrade.fitting.unpaired.steps.edges.farther`), and whose sharpening does not take it farther than
    its blur alone (:func:`~camdegrade.fitting.unpaired.steps.edges.sharpens_away`), the one of least spectrum
    mismatch; ``(0, 0)`` where the identity's mismatch is under :data:`SPECTRUM_FLOOR`, or where that choice
    neither halves it (:data:`SPECTRUM_GAIN`) nor brings the step width closer beyond the tolerance. And the
    record (widths not measured: ``None``)."""
    losses, widths, spread = proposal.losses, proposal.widths, proposal.spread
    base = widths.get((proposal.sigma, 0.0), math.nan)
    allowed = [
        (sigma, amount)
        for sigma, amount in losses
        if not farther(spread, base, widths.get((sigma, amount), math.nan))
        and not (amount > 0 and sharpens_away(spread, widths.get((sigma, 0.0), math.nan), widths[(sigma, amount)]))
    ]
    best = min(allowed, key=losses.__getitem__)
    identity, start = losses[(0.0, 0.0)], widths.get((0.0, 0.0), math.nan)
    off = abs(start - spread.width)
    closer = off > spread.tolerance and abs(widths[best] - spread.width) < off
    kept = identity > SPECTRUM_FLOOR and (losses[best] < SPECTRUM_GAIN * identity or closer)
    chosen = best if kept else (0.0, 0.0)
    spectrum_best = min(losses, key=losses.__getitem__)
    notes = {
        "identity_mismatch": round(identity, 4),
        "best_mismatch": round(losses[best], 4),
        "best": list(best),
        "by_spectrum_alone": list(spectrum_best),
        "edges": {
            **spread.record(),
            "blur_sigma": proposal.sigma,
            "chosen": rounded(widths.get(chosen, math.nan)),
            "by_spectrum_alone": rounded(widths.get(spectrum_best, math.nan)),
            "refused": [list(key) for key in sorted(set(losses) - set(allowed))],
        },
    }
    return chosen, notes


@dataclass(frozen=True)
class TransferMatch(UnpairedStep):
    """The blur and sharpening step (it needs the clean set): of the PSFs and unsharp masks whose simulation of the
    clean set keeps the captures' median step width (:mod:`~camdegrade.fitting.unpaired.steps.edges`), the one whose
    simulation has the captures' mean spectrum (the codec stage, read before it, simulated too); the spectrum alone
    where too few step edges are seen."""

    name: ClassVar[str] = "transfer"
    kinds: ClassVar[tuple[type[Effect], ...]] = (Blur, Sharpen)
    needs_clean: ClassVar[bool] = True

    def propose(self, fit: UnpairedFit) -> TransferProposal:
        use_blur, use_sharpen = fit.wants(Blur), fit.wants(Sharpen)
        widths: dict[tuple[float, float], float] = {}

        def simulate(sigma: float, amount: float) -> list[Tensor]:
            blur = Blur(sigma) if sigma > 0 and use_blur else None
            sharpen = Sharpen(SHARPEN_SIGMA, amount) if amount > 0 and use_sharpen else None
            images = fit.simulate(fit.chain(blur=blur, sharpen=sharpen), fit.sets.spectrum_crops, "unpaired-spectrum")
            widths[(sigma, amount)] = simulated_width(images)
            return images

        losses = transfer_mismatches(fit.sets.real_spectrum, simulate)
        spread = captures_edge_spread(fit)
        unsharpened = {sigma: width for (sigma, amount), width in widths.items() if amount == 0}
        sigma = (blur_by_edges(unsharpened, spread.width) if use_blur else 0.0) if spread.measured else None
        for amount in SHARPEN_AMOUNTS if sigma is not None and use_sharpen else ():
            if (sigma, amount) not in losses:
                losses[(sigma, amount)] = float(
                    (mean_spectrum(simulate(sigma, amount)) - fit.sets.real_spectrum).pow(2).mean()
                )
        return TransferProposal(losses, widths, spread, sigma)

    def judge(self, fit: UnpairedFit, proposal: TransferProposal) -> dict:
        if proposal.sigma is None or (0.0, 0.0) not in proposal.widths:
            (sigma, amount), notes = judge_transfer(proposal.losses)
        else:
            (sigma, amount), notes = judge_by_edges(proposal)
        fit.keep(Blur(sigma) if sigma > 0 and fit.wants(Blur) else None, Blur, Sharpen)
        fit.keep(Sharpen(SHARPEN_SIGMA, amount) if amount > 0 and fit.wants(Sharpen) else None)
        fit.say(f"blur and sharpening: sigma {sigma} px, amount {amount} (spectrum mismatch {notes})")
        return notes


@dataclass(frozen=True)
class DetailResponseMatch(UnpairedStep):
    """The detail response step (it needs the clean set): the radial response (:func:`radial_response`) that takes
    the simulated clean set's mean spectrum to the captures' after every other stage, kept by the halves' check
    (:func:`judge_detail_response`). On City100 (captures 036–055, clean 001–035) blur and sharpening leave 0.147,
    the response 0.001 (its halves: 0.168 → 0.020, 0.135 → 0.009), and on the 16 held-out pairs the 0.16–0.25
    cycles/pixel band goes from +0.51 to +0.09 log2 (``examples/fit_city100_unpaired.py``)."""

    name: ClassVar[str] = FrequencyResponse.name
    kinds: ClassVar[tuple[type[Effect], ...]] = (FrequencyResponse,)
    needs_clean: ClassVar[bool] = True

    def _simulate(self, fit: UnpairedFit) -> SimulateParts:
        def spectrum(gains: Tensor | None, part: slice) -> Tensor:
            chain = fit.chain(frequency_response=None if gains is None else radial_response(gains))
            return mean_spectrum(fit.simulate(chain, fit.sets.spectrum_crops[part], "unpaired-response"))

        return spectrum

    def propose(self, fit: UnpairedFit) -> ResponseProposal:
        fit.keep(None, FrequencyResponse)  # fitted afresh, after every other stage
        return propose_detail_response(fit.sets.real_spectra, self._simulate(fit))

    def judge(self, fit: UnpairedFit, proposal: ResponseProposal) -> dict:
        gains, notes = judge_detail_response(fit.sets.real_spectra, self._simulate(fit), proposal)
        if gains is not None and self._sharpens_away(fit, radial_response(gains), notes):
            gains, notes["kept"] = None, False
        fit.keep(None if gains is None else radial_response(gains))
        fit.say(f"detail response: {notes}")
        return notes

    def _sharpens_away(self, fit: UnpairedFit, response: FrequencyResponse, notes: dict) -> bool:
        """Whether ``response`` takes the simulation's median step width farther from the captures'
        (:func:`~camdegrade.fitting.unpaired.steps.edges.sharpens_away`); its widths go to ``notes``."""
        spread = captures_edge_spread(fit)
        if not spread.measured:
            return False
        crops = fit.sets.spectrum_crops
        without = simulated_width(fit.simulate(fit.chain(frequency_response=None), crops, "unpaired-response"))
        with_it = simulated_width(fit.simulate(fit.chain(frequency_response=response), crops, "unpaired-response"))
        away = sharpens_away(spread, without, with_it)
        notes["edges"] = {**spread.record(), "without": rounded(without), "with": rounded(with_it), "refused": away}
        return away
