"""The trace a digital upscale leaves in its images: spectral coherence at the sensor's period.

A row sampled at ``1/q`` of the output's resolution and interpolated back holds, at the frequencies ``f`` and
``f − 1/q`` cycles/pixel, the same sample's content through the interpolator's two gains: across the rows and
columns of many such images the two are coherent (near 1), where in any other image they are unrelated (near the
``1/√n`` of chance over ``n`` rows). The coherence is read from the images alone, so a camera's upscale is found
from its captures, paired or not. Measured (``examples/sensor_resolution.py``): 128² images upscaled 2×, 3× and 4×
read 0.89, 0.77 and 0.71 at their own period against 0.2 elsewhere; the captures of City100's iPhone X and of the
real-noise sets read the null (0.02–0.05).

References:
    A. C. Popescu, H. Farid, "Exposing digital forgeries by detecting traces of resampling", IEEE Trans. Signal
    Processing 53(2), 2005 (resampling leaves periodic correlations); W. A. Gardner, "Exploitation of spectral
    redundancy in cyclostationary signals", IEEE Signal Processing Magazine 8(2), 1991 (spectral coherence at a
    cycle frequency).
"""

from __future__ import annotations

import statistics
from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import Tensor

from camdegrade._pixels import as_unit
from camdegrade.functional.analysis import luma

#: The upscales looked for: a sensor of 1/2, 1/3 or 1/4 of the output's pixels per axis (their images repeat at
#: multiples of 1/q cycles/pixel; a non-integer factor such as 2/3 repeats beyond Nyquist and is not found).
PERIODS: tuple[int, ...] = (2, 3, 4)
#: Cycle frequencies no period of :data:`PERIODS` repeats at: their median coherence is the images' null.
CONTROL_SHIFTS: tuple[float, ...] = (0.29, 0.37, 0.43)
#: A period is found when its coherence exceeds the null by this much: upscaled sets exceed it by 0.49–0.72
#: (8-bit, 24 images of 128²), sets without an upscale by at most 0.09 (PolyU's clean means, whose demosaicking
#: leaves a weak period-2 trace).
MIN_EXCESS = 0.3
#: Frequencies this close to 0 or to Nyquist are left out: the window's leakage and the DC dominate there.
EDGE = 0.03


@dataclass(frozen=True)
class ResamplingTrace:
    """The coherence at each period of :data:`PERIODS` (``coherence[q]``, at ``1/q`` cycles/pixel), the images' null
    (median over :data:`CONTROL_SHIFTS`), the reference images' coherence where there were any (``reference[q]``:
    what the images held before the camera), and the period found (``None``: no upscale)."""

    coherence: dict[int, float]
    null: float
    reference: dict[int, float] | None
    period: int | None
    images: int

    def to_dict(self) -> dict:
        def rounded(values: dict[int, float] | None) -> dict[str, float] | None:
            return None if values is None else {str(q): round(value, 4) for q, value in values.items()}

        return {
            "coherence": rounded(self.coherence),
            "null": round(self.null, 4),
            "reference": rounded(self.reference),
            "period": self.period,
            "images": self.images,
            "min_excess": MIN_EXCESS,
        }


def cyclic_coherence(images: Sequence[Tensor], shift: float) -> float:
    """Mean over frequencies ``f`` of ``|Σ A·B̄| / √(Σ|A|² Σ|B|²)``, ``A`` the spectrum of a (Hann-windowed,
    mean-removed) row or column of the luma at ``f``, ``B`` at ``f − shift``, the sums over every row and column of
    ``images`` (``(3, H, W)``, uint8 or float) of one length; both frequencies in (:data:`EDGE`, 0.5 − EDGE)."""
    sums: dict[int, list[Tensor]] = {}
    for image in images:
        plane = luma(as_unit(image).double())
        for lines in (plane, plane.transpose(-1, -2)):
            length = lines.shape[-1]
            window = torch.hann_window(length, periodic=False, dtype=torch.float64)
            spectrum = torch.fft.fft((lines - lines.mean(-1, keepdim=True)) * window, dim=-1)
            here, there = _frequency_pairs(length, shift)
            first, second = spectrum[..., here], spectrum[..., there]
            terms = [(first * second.conj()).sum(0), first.abs().pow(2).sum(0), second.abs().pow(2).sum(0)]
            sums[length] = [a + b for a, b in zip(sums[length], terms)] if length in sums else terms
    per_bin = [cross.abs() / (power * partner).sqrt().clamp_min(1e-300) for cross, power, partner in sums.values()]
    values = torch.cat(per_bin)
    return float(values.mean()) if values.numel() else 0.0


def _frequency_pairs(length: int, shift: float) -> tuple[Tensor, Tensor]:
    """FFT indices of the positive frequencies ``f`` and of ``f − shift`` (wrapped), both within the band."""
    frequency = torch.fft.fftfreq(length, dtype=torch.float64)
    here = torch.nonzero((frequency > EDGE) & (frequency < 0.5 - EDGE)).flatten()
    there = (here - round(shift * length)) % length
    partner = frequency[there].abs()
    inside = (partner > EDGE) & (partner < 0.5 - EDGE)
    return here[inside], there[inside]


def resampling_trace(images: Sequence[Tensor], reference: Sequence[Tensor] | None = None) -> ResamplingTrace:
    """Whether ``images`` (a camera's captures, ``(3, H, W)`` each, at least 16 px a side) were upscaled from a
    sensor of ``1/q`` their resolution, ``q`` in :data:`PERIODS`: the period whose coherence exceeds the null by
    :data:`MIN_EXCESS` the most, or none. With ``reference`` (the clean images the camera saw, paired or not), the
    coherence must also exceed theirs by as much: an upscale the clean images already carry is not the camera's."""
    _check_images(images, "images")
    coherence = {period: cyclic_coherence(images, 1.0 / period) for period in PERIODS}
    null = statistics.median(cyclic_coherence(images, shift) for shift in CONTROL_SHIFTS)
    before = None
    if reference is not None:
        _check_images(reference, "reference")
        before = {period: cyclic_coherence(reference, 1.0 / period) for period in PERIODS}
    floor = {period: max(null, before[period]) if before else null for period in PERIODS}
    best = max(PERIODS, key=lambda period: coherence[period] - floor[period])
    found = best if coherence[best] - floor[best] >= MIN_EXCESS else None
    return ResamplingTrace(coherence, null, before, found, len(images))


def _check_images(images: Sequence[Tensor], name: str) -> None:
    if not images:
        raise ValueError(f"{name} must hold at least one image, got none")
    small = [tuple(image.shape[-2:]) for image in images if min(image.shape[-2:]) < 16]
    if small:
        raise ValueError(f"{name} must be at least 16x16 pixels, got {small[0][0]}x{small[0][1]}")
