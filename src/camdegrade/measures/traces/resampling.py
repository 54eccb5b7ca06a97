"""The trace a digital upscale leaves in its images: spectral coherence at the sensor's period.

A row sampled at ``1/q`` of the output's resolution and interpolated back holds, at the frequencies ``f`` and
``f − 1/q`` cycles/pixel, the same sample's content through the interpolator's two gains: across the rows and
columns of many such images the two are coherent (near 1), where in any other image they are unrelated (near the
``1/√n`` of chance over ``n`` rows). The coherence is read from the images alone, so a camera's upscale is found
from its captures, paired or not. Measured (``examples/sensor_resolution.py``): 128² images upscaled 2×, 3× and 4×
read 0.88, 0.77 and 0.71 at their own period against 0.02 elsewhere; the captures of City100's iPhone X read the
null (0.03), those of the real-noise sets at most 0.1 at 1/2 (their demosaicking's period-2 trace). JPEG's 8×8 grid
repeats at 1/4 and 1/2 as well (:data:`CODEC_SHIFTS`).

References:
    A. C. Popescu, H. Farid, "Exposing digital forgeries by detecting traces of resampling", IEEE Trans. Signal
    Processing 53(2), 2005 (resampling leaves periodic correlations); W. A. Gardner, "Exploitation of spectral
    redundancy in cyclostationary signals", IEEE Signal Processing Magazine 8(2), 1991 (spectral coherence at a
    cycle frequency).
"""

from __future__ import annotations

import statistics
from collections.abc import Sequence
from dataclasses import dataclass, replace

import torch
from torch import Tensor

from camdegrade._support.pixels import as_unit
from camdegrade.functional.analysis.images import luma

__all__ = [
    "CODEC_EXCESS",
    "CODEC_SHIFTS",
    "CONTROL_SHIFTS",
    "EDGE",
    "MIN_EXCESS",
    "PERIODS",
    "ResamplingTrace",
    "cyclic_coherence",
    "cyclic_coherences",
    "resampling_trace",
]

#: The upscales looked for: a sensor of 1/2, 1/3 or 1/4 of the output's pixels per axis (their images repeat at
#: multiples of 1/q cycles/pixel; a non-integer factor such as 2/3 repeats beyond Nyquist and is not found).
PERIODS: tuple[int, ...] = (2, 3, 4)
#: Cycle frequencies no period of :data:`PERIODS` repeats at: their median coherence is the images' null.
CONTROL_SHIFTS: tuple[float, ...] = (0.29, 0.37, 0.43)
#: JPEG's 8×8 blocks are periodic too, at every multiple of 1/8 cycles/pixel, 1/4 and 1/2 included: blurred photos
#: compressed at quality 10–50 read up to 0.73 above the null at 1/2 from their blocks alone. Their coherence at
#: 1/8 and 3/8, where no upscale of :data:`PERIODS` repeats, is what the periods on that grid (2 and 4) must also
#: exceed, by :data:`CODEC_EXCESS`.
CODEC_SHIFTS: tuple[float, ...] = (1 / 8, 3 / 8)
#: A period is found when its coherence exceeds the null (and the reference's) by this much: upscaled sets exceed
#: it by 0.49–0.72 (8-bit, 24 images of 128²), sets without an upscale by at most 0.09 (PolyU's clean means, whose
#: demosaicking leaves a weak period-2 trace) unless they are JPEGs (above).
MIN_EXCESS = 0.3
#: ... and, on the JPEG grid, the coherence at 1/8 and 3/8 by this much: JPEG alone exceeds it by at most 0.11 at
#: 1/2 (seven scikit-image photos, 24 crops of 128² each, blurred by 0, 1 or 2 px and compressed at quality 10, 20,
#: 50); 2× and 4× upscales then JPEG at quality 90 by 0.26–0.48, at 75 by 0.14–0.28, at 50 by 0.00–0.20: an upscale
#: compressed at quality 50 or below is mostly not found (``examples/sensor_resolution.py``).
CODEC_EXCESS = 0.15
#: Frequencies this close to 0 or to Nyquist are left out: the window's leakage and the DC dominate there.
EDGE = 0.03


@dataclass(frozen=True)
class ResamplingTrace:
    """The coherence at each period of :data:`PERIODS` (``coherence[q]``, at ``1/q`` cycles/pixel), the images' null
    (median over :data:`CONTROL_SHIFTS`), their coherence on the JPEG grid (``codec``, the largest over
    :data:`CODEC_SHIFTS`), the reference images' coherence where there were any (``reference[q]``: what the images
    held before the camera), and the period found (``None``: no upscale)."""

    coherence: dict[int, float]
    null: float
    codec: float
    reference: dict[int, float] | None
    period: int | None
    images: int

    def required(self, period: int) -> float:
        """The coherence at ``period`` that finds it: :data:`MIN_EXCESS` above the null and the reference's
        coherence there, and :data:`CODEC_EXCESS` above the JPEG grid's where the period's cycle frequency lies on
        that grid."""
        required = max(self.null, self.reference[period] if self.reference is not None else 0.0) + MIN_EXCESS
        return max(required, self.codec + CODEC_EXCESS) if 8 % period == 0 else required

    def to_dict(self) -> dict:
        def rounded(values: dict[int, float] | None) -> dict[str, float] | None:
            return None if values is None else {str(q): round(value, 4) for q, value in values.items()}

        return {
            "coherence": rounded(self.coherence),
            "null": round(self.null, 4),
            "codec": round(self.codec, 4),
            "reference": rounded(self.reference),
            "period": self.period,
            "images": self.images,
            "min_excess": MIN_EXCESS,
            "codec_excess": CODEC_EXCESS,
        }


def cyclic_coherence(images: Sequence[Tensor], shift: float) -> float:
    """Mean over frequencies ``f`` of ``|Σ A·B̄| / √(Σ|A|² Σ|B|²)``, ``A`` the spectrum of a (Hann-windowed,
    mean-removed) row or column of the luma at ``f``, ``B`` at ``f − shift``, the sums over every row and column of
    ``images`` (``(3, H, W)``, uint8 or float) of one length; both frequencies in (:data:`EDGE`, 0.5 − EDGE). Lines
    of different lengths are pooled per length and the lengths weighted by their number of lines, so one large
    image does not outweigh many small ones."""
    return cyclic_coherences(images, (shift,))[shift]


def cyclic_coherences(images: Sequence[Tensor], shifts: Sequence[float]) -> dict[float, float]:
    """:func:`cyclic_coherence` at each of ``shifts``, every line's spectrum computed once."""
    _check_images(images, "images")
    sums: dict[tuple[float, int], list[Tensor]] = {}
    lines_of: dict[int, int] = {}
    for image in images:
        plane = luma(as_unit(image).double())
        for lines in (plane, plane.transpose(-1, -2)):
            length = lines.shape[-1]
            window = torch.hann_window(length, periodic=False, dtype=torch.float64)
            spectrum = torch.fft.fft((lines - lines.mean(-1, keepdim=True)) * window, dim=-1)
            lines_of[length] = lines_of.get(length, 0) + lines.shape[0]
            for shift in shifts:
                here, there = _frequency_pairs(length, shift)
                first, second = spectrum[..., here], spectrum[..., there]
                terms = [(first * second.conj()).sum(0), first.abs().pow(2).sum(0), second.abs().pow(2).sum(0)]
                key = (shift, length)
                sums[key] = [a + b for a, b in zip(sums[key], terms)] if key in sums else terms
    out = {}
    for shift in shifts:
        means, weights = [], []
        for length, count in lines_of.items():
            cross, power, partner = sums[(shift, length)]
            per_bin = cross.abs() / (power * partner).sqrt().clamp_min(1e-300)
            if per_bin.numel():
                means.append(float(per_bin.mean()))
                weights.append(count)
        out[shift] = sum(m * w for m, w in zip(means, weights)) / sum(weights) if weights else 0.0
    return out


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
    sensor of ``1/q`` their resolution, ``q`` in :data:`PERIODS`: the largest period whose coherence reaches
    :meth:`ResamplingTrace.required` (above the null, and above the JPEG grid's coherence; a 4× upscale repeats at
    1/2 as well as at 1/4), or none. With ``reference`` (the clean images the camera saw, paired or
    not), the coherence must also exceed theirs by as much: an upscale the clean images already carry is not the
    camera's."""
    _check_images(images, "images")
    at = cyclic_coherences(images, (*(1.0 / period for period in PERIODS), *CONTROL_SHIFTS, *CODEC_SHIFTS))
    coherence = {period: at[1.0 / period] for period in PERIODS}
    null = statistics.median(at[shift] for shift in CONTROL_SHIFTS)
    codec = max(at[shift] for shift in CODEC_SHIFTS)
    before = None
    if reference is not None:
        _check_images(reference, "reference")
        clean = cyclic_coherences(reference, [1.0 / period for period in PERIODS])
        before = {period: clean[1.0 / period] for period in PERIODS}
    trace = ResamplingTrace(coherence, null, codec, before, None, len(images))
    found = [period for period in PERIODS if coherence[period] >= trace.required(period)]
    return replace(trace, period=max(found)) if found else trace


def _check_images(images: Sequence[Tensor], name: str) -> None:
    """``images`` must be a non-empty sequence of finite ``(3, H, W)`` images of at least 16 px a side."""
    if not images:
        raise ValueError(f"{name} must hold at least one image, got none")
    for index, image in enumerate(images):
        if image.ndim != 3 or image.shape[0] != 3:
            raise ValueError(f"{name} must be (3, H, W) images, got shape {tuple(image.shape)} at index {index}")
        if min(image.shape[-2:]) < 16:
            raise ValueError(f"{name} must be at least 16x16 pixels, got {image.shape[-2]}x{image.shape[-1]}")
        if image.is_floating_point() and not bool(torch.isfinite(image).all()):
            raise ValueError(f"{name} must be finite, got a NaN or infinite value at index {index}")
