"""The ``frequency`` family: the transfer function from the clean image to the image (a blur or sharpening MTF)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
from torch import Tensor

from camdegrade.functional.analysis.images import hann2d, luma, radial_frequency
from camdegrade.measures._common import ratio
from camdegrade.measures.base import MeasuredPair, PairedFamily, register_family

if TYPE_CHECKING:
    from camdegrade.measures.statistics import StatisticSet

__all__ = ["BANDS", "MIN_POWER", "Frequency", "band_index"]

BANDS = 8
#: Clean-image power in a band (summed over pairs) below which the transfer is not measured: float rounding of a
#: flat image gives about 1e-13; 8-bit quantisation alone of a 64² image about 1e-4.
MIN_POWER = 1e-8


def band_index(height: int, width: int) -> Tensor:
    """``(H, W // 2 + 1)`` radial band (of :data:`BANDS`) of each ``rfft2`` frequency; −1 for the lowest ones."""
    radius = radial_frequency(height, width)
    band = (radius / 0.5 * BANDS).long().clamp(max=BANDS - 1)
    return torch.where(radius < 1.0 / max(height, width), torch.full_like(band, -1), band)


@register_family
class Frequency(PairedFamily):
    """Transfer function ``Re(X·C*)/|C|²`` in 8 radial bands (luma), relative to the lowest band. A
    cross-statistic with the clean image, so independent noise averages out of it."""

    name = "frequency"
    tau = 0.02
    unit = "transfer ratio"
    description = "transfer function Re(X·C*)/|C|² in 8 radial bands (luma), relative to the lowest band"
    network_fault = "the network's high-frequency transfer"
    mixing = True

    def measure(self, pair: MeasuredPair) -> tuple[Tensor, Tensor]:
        x, c = pair.image, pair.clean
        height, width = c.shape[-2:]
        window = hann2d(height, width)
        lx, lc = luma(x), luma(c)
        spectrum_x = torch.fft.rfft2((lx - lx.mean()) * window)
        spectrum_c = torch.fft.rfft2((lc - lc.mean()) * window)
        cross = (spectrum_x * spectrum_c.conj()).real
        power = spectrum_c.abs().pow(2)
        band = band_index(height, width)
        valid = band >= 0
        num = torch.bincount(band[valid], weights=cross[valid].double(), minlength=BANDS)
        den = torch.bincount(band[valid], weights=power[valid].double(), minlength=BANDS)
        scale = float(height * width)
        return (num / scale).float(), (den / scale).float()

    def reduce(self, num: Tensor, den: Tensor) -> Tensor:
        """Sums → the transfer in bands 1.. relative to band 0; NaN where the clean images have too little texture
        (:data:`MIN_POWER`)."""
        h = torch.where(den > MIN_POWER, ratio(num, den), torch.nan)
        return h[..., 1:] / h[..., :1]

    def describe(self, real: Tensor, sim: Tensor, real_set: StatisticSet) -> str:
        band = BANDS - 3  # well above the lowest band, below the noisy top one
        frequency = (band + 1 + 0.5) / BANDS * 0.5
        if not bool(torch.isfinite(real[band])):
            return f"transfer not measurable at {frequency:.2f} cycles/px: the clean images have too little texture"
        transfer = real[band] / sim[band] if float(sim[band]) != 0 else float("nan")
        kind = "softer (blur)" if transfer < 1 else "sharper"
        return f"real/sim transfer at {frequency:.2f} cycles/px: {transfer:.2f} ({kind} than simulated)"
