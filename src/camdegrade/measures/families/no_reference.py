"""The no-reference families of the unpaired mode: statistics of one image alone, for captures of other scenes than
the clean images (each carries the signature of a paired family, :attr:`NoReferenceFamily.signature`)."""

from __future__ import annotations

import torch
from torch import Tensor

from camdegrade.functional import relative_radius
from camdegrade.functional.analysis.images import hann2d, high_pass, luma, relative_flat_mask
from camdegrade.measures.base import NoReferenceFamily, register_family
from camdegrade.measures.families.blocks import Blocks, block_phase_energy
from camdegrade.measures.families.color import ColorMatrix
from camdegrade.measures.families.frequency import BANDS, Frequency, band_index
from camdegrade.measures.families.intensity import Intensity
from camdegrade.measures.families.noise import NoiseLevel
from camdegrade.measures.families.spatial import Spatial

__all__ = ["NOISE_LEVELS", "RINGS", "BlockEnergy", "ColorRatios", "FlatNoise", "Radial", "Spectrum", "ToneQuantiles"]

RINGS = 8
NOISE_LEVELS = 4


@register_family
class Radial(NoReferenceFamily):
    """Mean luma in 8 rings of distance from the centre, relative to the central ring (vignetting)."""

    name = "radial"
    tau = 0.01
    unit = "ratio to the centre"
    description = "luma radial profile in 8 rings, relative to the centre"
    signature = Spatial.name

    def measure(self, image: Tensor) -> Tensor:
        gray = luma(image)
        height, width = gray.shape
        radius = relative_radius(height, width, torch.float32, gray.device)
        rings = (radius * RINGS).long().clamp(max=RINGS - 1)
        ring_mean = torch.bincount(rings.flatten(), weights=gray.flatten(), minlength=RINGS) / torch.bincount(
            rings.flatten(), minlength=RINGS
        ).clamp_min(1)
        return ring_mean / ring_mean[0].clamp_min(1e-4)


@register_family
class ColorRatios(NoReferenceFamily):
    """The image's R/G and B/G mean ratios."""

    name = "color"
    tau = 0.01
    unit = "ratio"
    description = "R/G and B/G means"
    signature = ColorMatrix.name

    def measure(self, image: Tensor) -> Tensor:
        means = image.mean((1, 2)).clamp_min(1e-4)
        return torch.stack([means[0] / means[1], means[2] / means[1]])


@register_family
class ToneQuantiles(NoReferenceFamily):
    """Luma quantiles 0.05, 0.1625, ..., 0.95 (on at most about 50,000 pixels)."""

    name = "tone"
    tau = 0.01
    unit = "luma"
    description = "luma quantiles from 0.05 to 0.95"
    signature = Intensity.name

    def measure(self, image: Tensor) -> Tensor:
        gray = luma(image)
        return torch.quantile(gray.flatten()[:: max(1, gray.numel() // 50_000)], torch.linspace(0.05, 0.95, 9))


@register_family
class Spectrum(NoReferenceFamily):
    """log10 mean power of the windowed luma in the paired ``frequency`` family's 8 radial bands (blur, noise)."""

    name = "spectrum"
    tau = 0.05
    unit = "log10 power"
    description = "log power in 8 radial frequency bands (luma)"
    signature = Frequency.name

    def measure(self, image: Tensor) -> Tensor:
        gray = luma(image)
        height, width = gray.shape
        spectrum = torch.fft.rfft2((gray - gray.mean()) * hann2d(height, width)).abs().pow(2)
        band = band_index(height, width)
        valid = band >= 0
        power = torch.bincount(band[valid], weights=spectrum[valid], minlength=BANDS) / torch.bincount(
            band[valid], minlength=BANDS
        ).clamp_min(1)
        return power.clamp_min(1e-12).log10()


@register_family
class BlockEnergy(NoReferenceFamily):
    """The paired ``blocks`` statistic of the image alone: gradient energy per 8×8 grid phase, relative to the mean."""

    name = "blocks"
    tau = 0.01
    unit = "relative gradient energy"
    description = "8×8 block-edge gradient energy relative to the mean"
    signature = Blocks.name

    def measure(self, image: Tensor) -> Tensor:
        num, den = block_phase_energy(image)
        return num / den.clamp_min(1e-12)


@register_family
class FlatNoise(NoReferenceFamily):
    """Std of the high-passed luma on the flattest 30 % of the image, in 4 brightness bins (NaN with ≤ 16 pixels)."""

    name = "noise"
    tau = 0.002
    unit = "luma std"
    description = "std of the high-passed luma on the image's own flattest pixels, 4 brightness bins"
    signature = NoiseLevel.name

    def measure(self, image: Tensor) -> Tensor:
        gray = luma(image)
        mask = relative_flat_mask(image, 0.3)
        residual = high_pass(gray)[mask]
        level = gray[mask]
        noise = torch.zeros(NOISE_LEVELS)
        for index in range(NOISE_LEVELS):
            chosen = residual[(level * NOISE_LEVELS).long().clamp(max=NOISE_LEVELS - 1) == index]
            noise[index] = chosen.std() if chosen.numel() > 16 else float("nan")
        return noise
