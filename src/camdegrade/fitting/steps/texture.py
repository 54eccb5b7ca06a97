"""A fit's texture stages: a blur and an ISP sharpening chosen so that the luma power spectrum of the sampled profile
matches the captures' in every band of :data:`~camdegrade.measures.fidelity.BAND_EDGES`.

A network fitted by least squares predicts the capture's conditional mean: detail whose exact position it cannot
predict is averaged away (too little power in the mid bands), while its linear filter passes fine detail that the
camera's optics removed, because the squared error barely weighs the faint top band (too much power there). Both
show to the eye at 2× and to a critic that sees the image alone; neither costs much PSNR. The bands of the sampled
profile are measured on the training pairs once; the blur's and the sharpening's transfer functions (radial, so
the power of each radial bin is only scaled) then predict the bands of every candidate without running it. The
stages are kept only where the validation pairs confirm it (:func:`judge_texture`).

References:
    R. C. Gonzalez, R. E. Woods, "Digital Image Processing", 4th ed., 2018, ch. 4 (unsharp masking and Gaussian
    low-pass filters as frequency-domain transfer functions);
    Y. Blau, T. Michaeli, "The Perception-Distortion Tradeoff", CVPR 2018 (why matching the distribution costs
    distortion).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from typing import ClassVar

import torch
from torch import Tensor

from camdegrade.effects import Blur, Effect, Sharpen
from camdegrade.fitting.steps.base import FitStep, PairedFit, Verdict
from camdegrade.functional.optics.blur import TRUNCATE
from camdegrade.measures.fidelity import BAND_EDGES, luma_spectrum
from camdegrade.measures.metrics import psnr
from camdegrade.profile import CameraProfile

__all__ = [
    "BLUR_SIGMAS",
    "DIRECTIONS",
    "GAUSSIAN_IDENTITY_SIGMA",
    "MAX_PSNR_LOSS_DB",
    "MIN_BAND_GAIN_LOG2",
    "RADIAL_BIN",
    "SHARPEN_AMOUNTS",
    "SHARPEN_SIGMAS",
    "TEXTURE_PAIRS",
    "TextureFit",
    "TextureMatch",
    "band_errors",
    "choose_texture",
    "gaussian_gain",
    "judge_texture",
    "predicted_error",
    "radial_powers",
    "transfer",
]

#: Candidate blur σ (pixels, on the sRGB values; 0: none), and unsharp-mask σ and amount (0: none).
BLUR_SIGMAS = (0.0, 0.3, 0.4, 0.5, 0.6, 0.7, 0.85, 1.0, 1.2, 1.5)
SHARPEN_SIGMAS = (0.5, 0.7, 1.0, 1.5, 2.0, 3.0)
SHARPEN_AMOUNTS = (0.0, 0.1, 0.2, 0.35, 0.5, 0.75, 1.0, 1.5, 2.0, 2.5, 3.0)
#: A Gaussian this narrow is the identity (its kernel is one tap:
#: :func:`~camdegrade.functional.optics.blur.psf_kernel`).
GAUSSIAN_IDENTITY_SIGMA = 0.05
#: Directions the gain of a separable kernel is averaged over, from 0 to 90 degrees.
DIRECTIONS = 16
#: Width (cycles/pixel) of the radial bins the spectrum is pooled in: every band edge is a multiple of it.
RADIAL_BIN = 0.005
_BINS = round(BAND_EDGES[-1] / RADIAL_BIN)
#: The stages are kept only if they lower the validation pairs' RMS band error (log2) by at least this much ...
MIN_BAND_GAIN_LOG2 = 0.1
#: ... and cost the profile's deterministic output at most this much validation PSNR (dB). Giving a least-squares
#: prediction the captures' spectrum costs PSNR by design: a sample of the posterior has up to twice the MMSE's
#: squared error, 3 dB (Blau and Michaeli). On City100 the stages kept cost the default fit 0.55 dB on its validation
#: pairs and 0.29 dB on the 16 held-out scenes (docs/fitting.md); the soft simulated camera's would have cost 2.1 dB.
MAX_PSNR_LOSS_DB = 1.0
#: At most this many training pairs fit them, and as many validation pairs judge them (City100: 16 frames of
#: 840×600, 8 M pixels each way).
TEXTURE_PAIRS = 16

Log = Callable[[str], None]


@dataclass(frozen=True)
class TextureFit:
    """The chosen stages' values and the evidence they were kept or dropped on."""

    blur_sigma: float
    sharpen_sigma: float
    sharpen_amount: float
    kept: bool
    train_error_before: float
    train_error_after: float
    val_error_before: float | None = None
    val_error_after: float | None = None
    val_psnr_before: float | None = None
    val_psnr_after: float | None = None

    def stages(self) -> list[Effect]:
        """The stages these values make (none for a neutral choice)."""
        stages: list[Effect] = []
        if self.blur_sigma > 0:
            stages.append(Blur(self.blur_sigma, linear=False))
        if self.sharpen_amount > 0:
            stages.append(Sharpen(self.sharpen_sigma, self.sharpen_amount))
        return stages

    def to_dict(self) -> dict:
        return {key: _rounded(value) for key, value in asdict(self).items()}


def _rounded(value: object) -> object:
    return round(value, 4) if isinstance(value, float) and math.isfinite(value) else value


def radial_powers(images: Sequence[Tensor]) -> Tensor:
    """``(N, B)``: each frame's luma power (:func:`~camdegrade.measures.fidelity.luma_spectrum`) summed in radial
    bins of :data:`RADIAL_BIN` up to 0.5 cycles/pixel."""
    rows = []
    for image in images:
        power, radius = luma_spectrum(image)
        index = (radius / RADIAL_BIN).floor().long().clamp(max=_BINS)  # bin _BINS gathers the corners, unused
        rows.append(torch.bincount(index.flatten(), weights=power[0].flatten(), minlength=_BINS + 1)[:_BINS])
    return torch.stack(rows)


def _bin_centres() -> Tensor:
    return (torch.arange(_BINS, dtype=torch.float64) + 0.5) * RADIAL_BIN


def _band_of_bins() -> Tensor:
    return torch.bucketize(_bin_centres(), torch.tensor(BAND_EDGES, dtype=torch.float64)) - 1


def band_errors(sim: Tensor, real: Tensor) -> Tensor:
    """``log2`` of the summed power of ``sim`` over ``real``'s per band, mean over frames (``(N, B)`` radial
    powers of the same frames): the bands of :func:`~camdegrade.measures.fidelity.band_log2_ratios`."""
    band = _band_of_bins()
    sums = [
        (sim[:, band == index].sum(-1).clamp_min(1e-12) / real[:, band == index].sum(-1).clamp_min(1e-12)).log2()
        for index in range(len(BAND_EDGES) - 1)
    ]
    return torch.stack(sums, -1).mean(0)


def gaussian_gain(sigma: float, frequency: Tensor) -> Tensor:
    """Amplitude gain at radial ``frequency`` (cycles/pixel) of the blur kernels'
    (:func:`~camdegrade.functional.optics.blur.psf_kernel`) sampled, truncated and normalised Gaussian of ``sigma``,
    averaged over directions: at small σ its gain near 0.5 cycles/pixel is well above the continuous Gaussian's."""
    if sigma <= GAUSSIAN_IDENTITY_SIGMA:
        return torch.ones_like(frequency)
    radius = math.ceil(TRUNCATE * sigma)
    taps = torch.arange(-radius, radius + 1, dtype=torch.float64)
    weights = torch.exp(-0.5 * (taps / sigma) ** 2)
    weights = weights / weights.sum()
    angles = torch.linspace(0.0, math.pi / 2, DIRECTIONS, dtype=torch.float64)

    def along(component: Tensor) -> Tensor:  # the 1-D gain of the separable kernel
        return (weights * torch.cos(2 * math.pi * component[..., None] * taps)).sum(-1)

    return (along(frequency[:, None] * angles.cos()) * along(frequency[:, None] * angles.sin())).mean(-1)


def transfer(blur_sigma: float, sharpen_sigma: float, amount: float, frequency: Tensor) -> tuple[Tensor, Tensor]:
    """Amplitude gains at radial ``frequency`` (cycles/pixel) of the blur ``G``, and of the unsharp mask
    ``x + a·(x − G_σ x)``, which passes ``1 + a·(1 − G_σ)``."""
    blur = gaussian_gain(blur_sigma, frequency)
    sharpen = 1 + amount * (1 - gaussian_gain(sharpen_sigma, frequency))
    return blur, sharpen


def predicted_error(
    clean_part: Tensor, noise_part: Tensor, real: Tensor, blur_sigma: float, sharpen_sigma: float, amount: float
) -> float:
    """RMS over bands of the predicted ``log2`` band error once the blur (before the noise: it is an optical stage)
    and the sharpening (after it: an ISP stage) are added."""
    blur, sharpen = transfer(blur_sigma, sharpen_sigma, amount, _bin_centres())
    predicted = sharpen.pow(2) * (blur.pow(2) * clean_part + noise_part)
    return float(band_errors(predicted, real).pow(2).mean().sqrt())


def choose_texture(clean_part: Tensor, noise_part: Tensor, real: Tensor) -> tuple[tuple[float, float, float], float]:
    """The candidate (blur σ, sharpen σ, amount) of least predicted band error, and that error."""
    candidates = itertools.product(BLUR_SIGMAS, SHARPEN_SIGMAS, SHARPEN_AMOUNTS)
    scored = [(predicted_error(clean_part, noise_part, real, *values), values) for values in candidates]
    error, values = min(scored, key=lambda item: item[0])
    return values, error


@dataclass(frozen=True)
class TextureMatch(FitStep):
    """The texture step: a blur and a sharpening chosen on the training pairs (:func:`choose_texture`: the
    candidates' band errors predicted from their transfer functions), kept where the validation pairs confirm them
    (:meth:`judge`); recorded in ``fitted['texture']``."""

    name: ClassVar[str] = "texture"
    needs_network: ClassVar[bool] = True

    def propose(self, fit: PairedFit) -> TextureFit | Verdict:
        profile, seed = fit.profile, fit.seed
        if any(isinstance(effect, (Blur, Sharpen)) for effect in profile.effects):
            fit.say("texture: the profile already has a blur or sharpen stage; not fitted")
            return Verdict({"kept": False, "reason": "the profile already has a blur or sharpen stage"})
        pairs = list(fit.train_pairs)[:TEXTURE_PAIRS]
        stages = _stages_of(profile)
        outputs = _network_outputs(profile, [clean for clean, _ in pairs])
        real = radial_powers([captured for _, captured in pairs])
        clean_part = radial_powers(stages.simulate(outputs, seed=seed, deterministic=True))
        sampled = radial_powers(stages.simulate(outputs, seed=seed, stream="texture"))
        noise_part = (sampled - clean_part).clamp_min(0.0)
        before = float(band_errors(sampled, real).pow(2).mean().sqrt())
        values, after = choose_texture(clean_part, noise_part, real)
        fitted = TextureFit(*values, kept=False, train_error_before=before, train_error_after=after)
        return Verdict(_verdict(fitted, fit.say)) if not fitted.stages() else fitted

    def judge(self, fit: PairedFit, fitted: TextureFit) -> dict:
        judged = judge_texture(fit.profile, fit.judge_pairs(TEXTURE_PAIRS), fitted, fit.seed)
        fit.keep(judged.kept, *judged.stages())
        return _verdict(judged, fit.say)


def _stages_of(profile: CameraProfile) -> CameraProfile:
    """``profile``'s effect stages alone, to run on its network's outputs."""
    return CameraProfile(None, list(profile.effects))


def _network_outputs(profile: CameraProfile, cleans: Sequence[Tensor]) -> list[Tensor]:
    """The network's output for each clean image (the clean images where the profile has no network)."""
    return profile.with_chain([]).simulate(cleans, seed=0, deterministic=True)


def judge_texture(
    profile: CameraProfile,
    pairs: Sequence[tuple[Tensor, Tensor]],
    fitted: TextureFit,
    seed: int,
) -> TextureFit:
    """``fitted`` with the evidence of ``pairs`` (the validation pairs): kept when ``profile`` with its stages
    lowers their RMS band error by :data:`MIN_BAND_GAIN_LOG2` and costs at most :data:`MAX_PSNR_LOSS_DB` of the
    deterministic output's PSNR."""
    outputs = _network_outputs(profile, [clean for clean, _ in pairs])
    captures = [captured for _, captured in pairs]
    real = radial_powers(captures)
    errors, scores = [], []
    for stages in (_stages_of(profile), _stages_of(profile.with_effects(*fitted.stages()))):
        sampled = radial_powers(stages.simulate(outputs, seed=seed, stream="texture-check"))
        errors.append(float(band_errors(sampled, real).pow(2).mean().sqrt()))
        means = stages.simulate(outputs, seed=seed, deterministic=True)
        scores.append(sum(psnr(mean, captured) for mean, captured in zip(means, captures)) / len(captures))
    kept = errors[0] - errors[1] >= MIN_BAND_GAIN_LOG2 and scores[0] - scores[1] <= MAX_PSNR_LOSS_DB
    return replace(
        fitted,
        kept=kept,
        val_error_before=errors[0],
        val_error_after=errors[1],
        val_psnr_before=scores[0],
        val_psnr_after=scores[1],
    )


def _verdict(fitted: TextureFit, say: Log) -> dict:
    """``fitted``'s record, said on the log."""
    word = "kept" if fitted.kept else "dropped"
    evidence = (
        f"; validation band error {fitted.val_error_before:.2f} -> {fitted.val_error_after:.2f} log2, PSNR "
        f"{fitted.val_psnr_before:.2f} -> {fitted.val_psnr_after:.2f} dB"
        if fitted.val_error_before is not None
        else ""
    )
    say(
        f"texture: blur sigma {fitted.blur_sigma}, sharpen sigma {fitted.sharpen_sigma} amount "
        f"{fitted.sharpen_amount} -> {word} (training band error {fitted.train_error_before:.2f} -> "
        f"{fitted.train_error_after:.2f} log2{evidence})"
    )
    return fitted.to_dict()
