"""Coherence of two sets of images per radial frequency, and the random displacement it implies.

The coherence of ``a`` and ``b`` at a frequency is ``Re Σ A·B* / √(Σ|A|² Σ|B|²)`` over the images (luma, mean
removed, Hann window): 1 where ``b`` holds ``a``'s detail at any gain, 0 where what it holds there is unrelated.
A random displacement of ``σ`` pixels per axis (Gaussian) multiplies it by ``exp(−2π² f² σ²)``: the expected
phase factor ``E[exp(−2πi f·δ)]``. Additive texture (noise, aliasing, a codec) lowers it too, but by its share of
the power, which grows where the content's power falls; where the content dominates (coherence near 1) the loss is
the displacement's.

References:
    J. S. Bendat, A. G. Piersol, "Random Data: Analysis and Measurement Procedures", 4th ed., 2010, ch. 9
    (coherence functions).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import Tensor

from camdegrade.functional.analysis.images import hann2d, luma, radial_frequency

__all__ = ["BIN", "DETAIL_ABOVE", "HIGH_COHERENCE", "bin_centres", "coherence", "cross_spectra", "displacement_sigma"]

#: Width of the radial frequency bins (cycles/pixel).
BIN = 0.02
#: The bins below this (cycles/pixel) hold the frames' shading and tone, not their detail: never read.
DETAIL_ABOVE = 2 * BIN
#: Bins where the coherence to explain is at least this read the displacement: there a loss is first order in the
#: displacement's variance and the texture's share of the power is small (City100: the captures' coherence with
#: the network's output falls from 0.99 to 0.83 over 0.02–0.16 cycles/pixel as a displacement of 0.58 px would,
#: and then faster, to 0.15 at 0.23, where the content's power has fallen 30-fold).
HIGH_COHERENCE = 0.8
BINS = int(0.5 / BIN)


def bin_centres() -> Tensor:
    """The centre of each radial bin (cycles/pixel), ``(BINS,)``, float64."""
    return (torch.arange(BINS, dtype=torch.float64) + 0.5) * BIN


def cross_spectra(first: Sequence[Tensor], second: Sequence[Tensor]) -> Tensor:
    """``(3, BINS)`` float64 sums over the image pairs and over each bin's frequencies: ``Re A·B*``, ``|A|²``,
    ``|B|²`` of the lumas of ``first[i]`` and ``second[i]`` (``(3, H, W)`` each, one size per pair)."""
    sums = torch.zeros(3, BINS, dtype=torch.float64)
    for a, b in zip(first, second, strict=True):
        if a.shape[-2:] != b.shape[-2:]:
            raise ValueError(f"each pair must be of one size, got {tuple(a.shape)} and {tuple(b.shape)}")
        height, width = a.shape[-2:]
        window = hann2d(height, width, torch.float64)
        spectra = []
        for image in (a, b):
            y = luma(image.detach().double().cpu())
            spectra.append(torch.fft.rfft2((y - y.mean()) * window))
        index = (radial_frequency(height, width, torch.float64) / BIN).floor().long().flatten()
        inside = index < BINS
        first_spectrum, second_spectrum = (s.flatten()[inside] for s in spectra)
        values = torch.stack(
            [(first_spectrum * second_spectrum.conj()).real, first_spectrum.abs() ** 2, second_spectrum.abs() ** 2]
        )
        sums.index_add_(1, index[inside], values)
    return sums


def coherence(first: Sequence[Tensor], second: Sequence[Tensor]) -> Tensor:
    """``(BINS,)`` float64: the coherence of each pair's images per radial bin, pooled over the pairs (module
    docstring); 0 where a bin holds no power."""
    cross, power_a, power_b = cross_spectra(first, second)
    return torch.where(power_a * power_b > 0, cross / (power_a * power_b).clamp_min(1e-300).sqrt(), 0.0)


def displacement_sigma(explained: Tensor, observed: Tensor, floor: float = HIGH_COHERENCE) -> float | None:
    """The displacement (pixels per axis) that takes the coherence ``explained`` per bin (what a model already
    gives) to ``observed`` (the captures'): least squares of ``−ln(observed / explained) = 2π² f² σ²`` through 0
    over the bins above :data:`DETAIL_ABOVE` where both are at least ``floor``; 0 where the captures are not less
    coherent, ``None`` where fewer than 3 bins qualify."""
    centres = bin_centres()
    usable = (centres > DETAIL_ABOVE) & (explained >= floor) & (observed >= floor)
    if int(usable.sum()) < 3:
        return None
    x = 2 * math.pi**2 * centres[usable] ** 2
    y = -torch.log(observed[usable] / explained[usable])
    variance = float((x * y).sum() / (x * x).sum())
    return math.sqrt(variance) if variance > 0 else 0.0
