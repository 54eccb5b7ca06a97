"""Fidelity: how close a set of simulated images is to the camera's own captures, read from the images.

Three looks that a trained model also gets, each a ratio or a difference of simulation against capture of the
same clean images (1 or 0: the same):

- **grid** (:func:`grid_rms`): the RMS of the pattern that repeats every 4 pixels in both directions. A decoder of
  transposed convolutions with stride 2, twice (the paper's network), prints such a 4-pixel period; a camera does
  not.
- **texture** (:func:`band_log2_ratios`): the luminance power spectrum in five radial bands, ``log2(sim / real)``
  (negative: too smooth; positive: too sharp or too noisy).
- **flat noise** (:func:`noise_ratios`): the noise std and the row banding where the clean image is flat
  (:func:`~camdegrade.functional.analysis.images.flat_mask`,
  :class:`~camdegrade.functional.analysis.noise.NoiseSums`), of the clean images that hold no noise or fine texture
  of their own there where some do (:func:`quiet_masks`).

Every function takes ``[N, 3, H, W]`` or ``[3, H, W]`` float images in [0, 1]; :func:`measure_fidelity` pools
them over a set of frames of any sizes into a :class:`FidelityReport`. The learned critic, which asks the same
question of a small CNN, is :mod:`camdegrade.measures.critic` (``image_only=True`` for what a model sees).

References:
    A. Odena, V. Dumoulin, C. Olah, "Deconvolution and Checkerboard Artifacts", Distill, 2016.
    S. Hegde et al., "A Simple Domain Shifting Network for Generating Low Quality Images", 2020.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import torch
from torch import Tensor

from camdegrade.functional.analysis.images import box_mean, flat_mask, hann2d, luma, radial_frequency
from camdegrade.functional.analysis.noise import NoiseSums

__all__ = [
    "BAND_EDGES",
    "GRID_HIGH_PASS",
    "GRID_PERIOD",
    "MIN_BAND_POWER",
    "MIN_ROW_STD_LEVELS",
    "QUIET_CLEAN_LEVELS",
    "QUIET_SHARE",
    "FidelityReport",
    "band_log2_ratios",
    "band_power",
    "grid_phases",
    "grid_rms",
    "luma_spectrum",
    "measure_fidelity",
    "noise_ratios",
    "quiet_masks",
]

#: Period (pixels) of the grid that two stride-2 transposed convolutions print.
GRID_PERIOD = 4
#: Side of the local mean taken off before the grid is averaged (smooth content is not a grid).
GRID_HIGH_PASS = 9
#: Edges (cycles per pixel, radial) of the five texture bands; frequencies beyond 0.5 (the corners) are left out.
BAND_EDGES = (0.02, 0.08, 0.16, 0.25, 0.35, 0.5)
#: Band power (summed, per frame) below which a band is not measured: a flat frame has none to compare.
MIN_BAND_POWER = 1e-8


def _batched(image: Tensor, name: str) -> Tensor:
    if not isinstance(image, Tensor) or image.dim() not in (3, 4) or image.shape[-3] != 3:
        shape = tuple(image.shape) if isinstance(image, Tensor) else type(image).__name__
        raise ValueError(f"{name} must be a float image [N, 3, H, W] or [3, H, W] in [0, 1], got {shape}")
    if not image.is_floating_point():
        raise TypeError(f"{name} must be a float image in [0, 1], got dtype {image.dtype}")
    return image if image.dim() == 4 else image[None]


def grid_phases(image: Tensor) -> Tensor:
    """``(N, 4, 4)``: the high-pass luma ``Y − box9(Y)`` (8-bit levels) averaged per phase ``(y mod 4, x mod 4)``
    over each frame, less its mean over the phases (what is left is the 4-periodic pattern alone)."""
    image = _batched(image, "image")
    height, width = (size - size % GRID_PERIOD for size in image.shape[-2:])
    if min(height, width) < GRID_PERIOD:
        raise ValueError(f"image must be at least {GRID_PERIOD}x{GRID_PERIOD} pixels, got {tuple(image.shape)}")
    gray = luma(image.to(torch.float32)) * 255.0
    detail = (gray - box_mean(gray, GRID_HIGH_PASS))[..., :height, :width].double()
    tiles = detail.reshape(-1, height // GRID_PERIOD, GRID_PERIOD, width // GRID_PERIOD, GRID_PERIOD)
    phases = tiles.mean((1, 3))
    return phases - phases.mean((-2, -1), keepdim=True)


def grid_rms(image: Tensor) -> float:
    """The RMS (8-bit levels) of the 4×4-periodic pattern of :func:`grid_phases`, mean over the frames.

    Random noise of std σ leaves about ``σ / sqrt(H·W / 16)`` here; a network's grid stays whatever the frame size.

    References:
        A. Odena, V. Dumoulin, C. Olah, "Deconvolution and Checkerboard Artifacts", Distill, 2016.
    """
    return float(grid_phases(image).pow(2).mean((-2, -1)).sqrt().mean())


def luma_spectrum(image: Tensor) -> tuple[Tensor, Tensor]:
    """``(N, H, W // 2 + 1)`` luma power (levels², Hann window, mean removed) of each frame per frequency, per pixel
    of the frame, and ``(H, W // 2 + 1)`` the radial frequency of each (cycles/pixel)."""
    image = _batched(image, "image")
    height, width = image.shape[-2:]
    gray = luma(image.to(torch.float32)) * 255.0
    gray = gray - gray.mean((-2, -1), keepdim=True)
    power = torch.fft.rfft2(gray * hann2d(height, width)).abs().pow(2).double() / float(height * width)
    radius = radial_frequency(height, width)
    return power, radius


def band_power(image: Tensor) -> Tensor:
    """``(N, 5)`` luma power (:func:`luma_spectrum`) of each frame in the bands of :data:`BAND_EDGES`."""
    power, radius = luma_spectrum(image)
    band = torch.bucketize(radius, torch.tensor(BAND_EDGES), right=True) - 1  # −1 below, len(BAND_EDGES) − 1 above
    band = torch.where(radius == BAND_EDGES[-1], len(BAND_EDGES) - 2, band)
    inside = (band >= 0) & (band < len(BAND_EDGES) - 1)
    sums = [power[:, inside & (band == index)].sum(-1) for index in range(len(BAND_EDGES) - 1)]
    return torch.stack(sums, -1)


def band_log2_ratios(sim: Tensor, real: Tensor) -> list[float | None]:
    """Per band of :data:`BAND_EDGES`, the mean over frames of ``log2(power(sim) / power(real))``; ``None`` where a
    frame of either has less than :data:`MIN_BAND_POWER` in that band. ``sim`` and ``real`` are frames of the same
    scenes, in the same order, of the same size (0 everywhere: the same texture; −1: half the power)."""
    sim, real = _batched(sim, "sim"), _batched(real, "real")
    if sim.shape != real.shape:
        raise ValueError(f"sim and real must have the same shape, got {tuple(sim.shape)} and {tuple(real.shape)}")
    return _mean_log2(band_power(sim), band_power(real))


def _mean_log2(sim_power: Tensor, real_power: Tensor) -> list[float | None]:
    measurable = ((sim_power >= MIN_BAND_POWER) & (real_power >= MIN_BAND_POWER)).all(0)
    ratios = torch.log2(sim_power.clamp_min(MIN_BAND_POWER) / real_power.clamp_min(MIN_BAND_POWER)).mean(0)
    return [float(value) if ok else None for value, ok in zip(ratios.tolist(), measurable.tolist(), strict=True)]


#: Row-mean std (8-bit levels) that :func:`noise_ratios` does not read as banding: the rows of a noiseless 8-bit
#: camera's flat captures do not vary (0.002 levels on the soft simulated camera's charts), and a simulation of
#: them, rounded to 8 bits, leaves 0.02 levels: a ratio of 11 that is rounding, not banding. City100's captures
#: hold 0.30 levels, the dark simulated camera's 1.7 (examples/simulated_camera_fidelity.py).
MIN_ROW_STD_LEVELS = 0.05


def noise_ratios(sim: NoiseSums, real: NoiseSums) -> tuple[float | None, float | None]:
    """``(noise, banding)``: the flat-pixel noise std of ``sim`` over ``real``'s, and the same of the std of the
    per-row means (row banding, RMS over channels), each raised to :data:`MIN_ROW_STD_LEVELS` first (rows that
    vary less than that are flat: two such give 1); ``None`` where either is not measurable (too few flat pixels
    or rows, :mod:`camdegrade.functional.analysis.noise`)."""
    noise = _finite(sim.pooled_std() / real.pooled_std()) if real.pooled_std() > 0 else None
    rows_sim = float(sim.line_variance()[0][0].mean().sqrt())
    rows_real = float(real.line_variance()[0][0].mean().sqrt())
    measurable = math.isfinite(rows_sim) and math.isfinite(rows_real)
    banding = max(rows_sim, MIN_ROW_STD_LEVELS) / max(rows_real, MIN_ROW_STD_LEVELS) if measurable else None
    return noise, banding


#: A clean image whose flat pixels hold less than this of their own (8-bit levels; rounding a smooth field leaves
#: 0.29) is quiet: what a capture holds there beyond the simulation is the camera's noise. A photo's "flat" sky or
#: wall holds fine texture or noise of 0.6–13 levels (the foreign cameras' photo crops; City100's, PolyU's, CC15's
#: and SIDD's clean images 0.49–4.4), which a camera's resampler and the profile's treat differently: read as
#: noise, it gave a noiseless camera a noise stage (docs/results.md, "Noise the flat-noise statistic did not see").
QUIET_CLEAN_LEVELS = 0.5
#: ... and the quiet images are measured alone where they hold at least this share of the flat pixels.
QUIET_SHARE = 0.25


def quiet_masks(cleans: Sequence[Tensor], masks: Sequence[Tensor]) -> list[Tensor]:
    """``masks`` (the flat pixels of ``cleans``) of the quiet clean images (:data:`QUIET_CLEAN_LEVELS`), the others'
    emptied, where the quiet ones hold :data:`QUIET_SHARE` of the flat pixels; all of ``masks`` otherwise (real
    pairs' clean images are photos with noise of their own: none of City100's 73 is quiet)."""
    own = [
        NoiseSums.measure(clean.to(torch.float32), clean, mask).pooled_std()
        for clean, mask in zip(cleans, masks, strict=True)
    ]
    quiet = [math.isfinite(level) and level < QUIET_CLEAN_LEVELS for level in own]
    pixels = [int(mask.sum()) for mask in masks]
    quiet_pixels = sum(count for count, keep in zip(pixels, quiet, strict=True) if keep)
    if quiet_pixels == 0 or quiet_pixels < QUIET_SHARE * sum(pixels):
        return list(masks)
    return [mask if keep else torch.zeros_like(mask) for mask, keep in zip(masks, quiet, strict=True)]


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


@dataclass
class FidelityReport:
    """How close simulated frames are to the captures of the same clean frames (see the module).

    Attributes:
        frames: frames measured.
        pixels: pixels of all frames (what the grid and the bands rest on).
        grid_sim, grid_real: :func:`grid_rms` of each (levels), mean over frames; ``grid_ratio`` their ratio.
        bands: :func:`band_log2_ratios` per band of :data:`BAND_EDGES` (``None``: not measurable).
        flat_pixels, rows: flat pixels and rows the noise and banding ratios rest on (of the captures).
        noise_ratio, banding_ratio: :func:`noise_ratios` (``None``: too few flat pixels or rows).
        psnr: mean paired PSNR (dB) of simulation against capture, over frames.
    """

    frames: int
    pixels: int
    grid_sim: float
    grid_real: float
    grid_ratio: float | None
    bands: list[float | None]
    flat_pixels: int
    rows: int
    noise_ratio: float | None
    banding_ratio: float | None
    psnr: float

    def to_dict(self, digits: int = 4) -> dict:
        """Strict JSON: numbers rounded, ``None`` for not measurable, the band edges alongside."""
        out = asdict(self)
        for key, value in out.items():
            if isinstance(value, float):
                out[key] = round(value, digits)
        out["bands"] = [None if value is None else round(value, digits) for value in self.bands]
        out["band_edges"] = list(BAND_EDGES)
        return out


def measure_fidelity(sims: Sequence[Tensor], reals: Sequence[Tensor], cleans: Sequence[Tensor]) -> FidelityReport:
    """The :class:`FidelityReport` of simulated frames against the captures, with the clean frames they came from
    (each ``[3, H, W]`` float in [0, 1]; frames may differ in size; the three lists in the same order)."""
    if not (len(sims) == len(reals) == len(cleans)) or not sims:
        raise ValueError(
            f"sims, reals and cleans must be non-empty and as long, got {len(sims)}, {len(reals)}, {len(cleans)}"
        )
    sim_sums, real_sums = NoiseSums.zeros(), NoiseSums.zeros()
    grids, powers, errors = [], [], []
    masks = quiet_masks(cleans, [flat_mask(clean) for clean in cleans])
    for sim, real, clean, mask in zip(sims, reals, cleans, masks, strict=True):
        grids.append((grid_rms(sim), grid_rms(real)))
        powers.append((band_power(sim)[0], band_power(real)[0]))
        sim_sums = sim_sums + NoiseSums.measure(sim.to(torch.float32), clean, mask)
        real_sums = real_sums + NoiseSums.measure(real.to(torch.float32), clean, mask)
        errors.append(float((sim.double() - real.double()).pow(2).mean()))
    grid_sim = sum(g for g, _ in grids) / len(grids)
    grid_real = sum(g for _, g in grids) / len(grids)
    noise, banding = noise_ratios(sim_sums, real_sums)
    return FidelityReport(
        frames=len(sims),
        pixels=sum(int(real.shape[-1] * real.shape[-2]) for real in reals),
        grid_sim=grid_sim,
        grid_real=grid_real,
        grid_ratio=grid_sim / grid_real if grid_real > 0 else None,
        bands=_mean_log2(torch.stack([p for p, _ in powers]), torch.stack([p for _, p in powers])),
        flat_pixels=real_sums.pixels,
        rows=int(real_sums.line_count()[0]),
        noise_ratio=noise,
        banding_ratio=banding,
        psnr=sum(10 * math.log10(1 / max(error, 1e-12)) for error in errors) / len(errors),
    )
