"""Global sub-pixel registration of (clean, captured) pairs: estimate a translation and undo it.

Convention used throughout: a shift ``(dy, dx)`` means ``moving(y, x) ≈ reference(y - dy, x - dx)``, i.e. the
content of ``moving`` sits ``dy`` pixels lower and ``dx`` pixels further right than in ``reference``, and
``apply_shift(reference, dy, dx) ≈ moving``.

The estimator is a phase correlation made robust for real captures: both images are reduced to zero-mean,
unit-variance luma and Hann-windowed; the cross-power spectrum is only half whitened (divided by the square root
of its magnitude) and weighted by a Gaussian low-pass, so blur, sensor noise, vignetting and colour casts in the
capture do not swamp the peak. The peak is located to 0.01 px with a matrix-multiply (upsampled) DFT around the
integer maximum, then re-estimated on the overlapping crops so that the window does not bias large shifts.

References:
    C. D. Kuglin, D. C. Hines, "The phase correlation image alignment method", Proceedings of the IEEE
    Conference on Cybernetics and Society, 1975; M. Guizar-Sicairos, S. T. Thurman, J. R. Fienup, "Efficient
    subpixel image registration algorithms", Optics Letters 33(2), 2008 (the upsampled DFT around the peak).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

import torch
import torch.nn.functional as F
from torch import Tensor

from camdegrade.functional.analysis.images import hann2d, luma

__all__ = [
    "AlignmentResult",
    "align_pair",
    "apply_shift",
    "estimate_shift",
    "format_shifts",
    "register",
]

_LOWPASS_SIGMA = 0.15  # cycles/pixel; captures rarely carry reliable phase above this
_MIN_SIDE = 8
_REFINE_ROUNDS = 3
_PAD_MARGIN = 16  # reflected pixels beyond the shift, so the FFT wrap-around seam stays far from valid pixels


@dataclass(frozen=True)
class AlignmentResult:
    """A registration: ``moving`` is ``reference`` moved by ``(dy, dx)`` pixels.

    ``score`` is the Pearson correlation of the two images' luma over their overlap once aligned (1 = identical up
    to gain and offset); values well below the pair set's typical score flag a pair whose shift is unreliable.
    """

    dy: float
    dx: float
    score: float

    @property
    def shift(self) -> tuple[float, float]:
        return (self.dy, self.dx)

    def __str__(self) -> str:
        return f"dy={self.dy:+.2f} dx={self.dx:+.2f} score={self.score:.3f}"


def estimate_shift(reference: Tensor, moving: Tensor) -> tuple[float, float]:
    """Estimate the global sub-pixel translation ``(dy, dx)`` that carries ``reference`` onto ``moving``.

    Args:
        reference: image ``(3, H, W)`` or ``(H, W)``, uint8 or float.
        moving: image of the same height and width (its channel count and dtype may differ).

    Returns:
        ``(dy, dx)`` in pixels, accurate to a few hundredths of a pixel on natural images, also when ``moving``
        is blurred, noisy or colour-shifted relative to ``reference``. Shifts are found modulo the image size,
        so only shifts below half the image size in each direction are recovered.
    """
    ref, mov = _luma_pair(reference, moving)
    return _estimate(ref, mov)


def register(reference: Tensor, moving: Tensor) -> AlignmentResult:
    """Like :func:`estimate_shift`, plus a score telling how well the two images agree once aligned."""
    ref, mov = _luma_pair(reference, moving)
    dy, dx = _estimate(ref, mov)
    return AlignmentResult(dy=dy, dx=dx, score=_aligned_correlation(ref, mov, dy, dx))


def apply_shift(image: Tensor, dy: float, dx: float) -> Tensor:
    """Translate ``image`` by ``(dy, dx)`` pixels: ``out(y, x) = image(y - dy, x - dx)``.

    The shift is applied as a Fourier phase ramp on a reflect-padded copy, so sub-pixel shifts do not blur (unlike
    bilinear resampling) and integer shifts are exact. Pixels that had no source (``ceil(|dy|)`` rows and
    ``ceil(|dx|)`` columns on the side the content moved away from) hold mirrored content: crop them, as
    :func:`align_pair` does.

    Args:
        image: ``(..., H, W)`` uint8 or floating tensor; not modified.

    Returns:
        Tensor of the same shape, dtype and device (uint8 is rounded and clamped).
    """
    if not isinstance(image, Tensor):
        raise TypeError(f"image must be a torch.Tensor, got {type(image).__name__}")
    if image.ndim < 2:
        raise ValueError(f"image must have shape (..., H, W), got shape {tuple(image.shape)}")
    if image.dtype != torch.uint8 and not image.is_floating_point():
        raise TypeError(f"image must be uint8 or floating point, got dtype {image.dtype}")
    height, width = image.shape[-2:]
    if abs(dy) >= height or abs(dx) >= width:
        raise ValueError(f"shift (dy={dy}, dx={dx}) must be smaller than the image size {height}x{width}")
    if dy == 0 and dx == 0:
        return image.clone()

    work_dtype = torch.float64 if image.dtype == torch.float64 else torch.float32
    flat = image.reshape(-1, height, width).to(work_dtype)
    pad_y = min(math.ceil(abs(dy)) + _PAD_MARGIN, height - 1)
    pad_x = min(math.ceil(abs(dx)) + _PAD_MARGIN, width - 1)
    padded = F.pad(flat, (pad_x, pad_x, pad_y, pad_y), mode="reflect")
    spectrum = torch.fft.fft2(padded)
    ramp = _phase_ramp(padded.shape[-2], padded.shape[-1], dy, dx, padded.device).to(spectrum.dtype)
    shifted = torch.fft.ifft2(spectrum * ramp).real
    out = shifted[:, pad_y : pad_y + height, pad_x : pad_x + width].reshape(image.shape)
    if image.dtype == torch.uint8:
        return out.round().clamp(0, 255).to(torch.uint8)
    return out.to(image.dtype)


def align_pair(
    clean: Tensor,
    captured: Tensor,
    *,
    move: Literal["clean", "captured"] = "clean",
) -> tuple[Tensor, Tensor, AlignmentResult]:
    """Register a pair, undo the translation and crop both images to the pixels valid in both.

    By default the *clean* image is moved onto the capture: the capture is the training target, and leaving it
    untouched keeps its real noise, blur and compression artefacts free of resampling and re-quantisation, while
    a Fourier shift of the clean image is close to lossless. ``move="captured"`` moves the capture instead, keeping
    the clean image's pixel grid.

    Args:
        clean: ``(3, H, W)`` uint8 or float.
        captured: ``(3, H, W)`` of the same height and width.
        move: which image is resampled.

    Returns:
        ``(clean_aligned, captured_aligned, result)``: two images of the same (smaller) size and dtypes as the
        inputs, pixel-aligned, and the registration found (``result.shift`` carries ``clean`` onto ``captured``).
    """
    if move not in ("clean", "captured"):
        raise ValueError(f"move must be 'clean' or 'captured', got move={move!r}")
    result = register(clean, captured)
    dy, dx = result.shift
    if move == "clean":
        clean = apply_shift(clean, dy, dx)
        rows, cols = _valid_span(dy, clean.shape[-2]), _valid_span(dx, clean.shape[-1])
    else:
        captured = apply_shift(captured, -dy, -dx)
        rows, cols = _valid_span(-dy, clean.shape[-2]), _valid_span(-dx, clean.shape[-1])
    if rows.stop - rows.start < _MIN_SIDE or cols.stop - cols.start < _MIN_SIDE:
        raise ValueError(
            f"shift (dy={dy:.2f}, dx={dx:.2f}) leaves less than {_MIN_SIDE} valid pixels of the "
            f"{clean.shape[-2]}x{clean.shape[-1]} pair; the images probably do not show the same scene"
        )
    return clean[..., rows, cols], captured[..., rows, cols], result


def format_shifts(results: Mapping[str, AlignmentResult]) -> str:
    """A plain-text table of per-pair registrations (name, dy, dx, score) with a summary line."""
    if not results:
        return "no pairs registered"
    width = max(len(name) for name in results)
    lines = [f"{'pair':<{width}}  {'dy':>7}  {'dx':>7}  {'score':>6}"]
    lines += [f"{name:<{width}}  {r.dy:+7.2f}  {r.dx:+7.2f}  {r.score:6.3f}" for name, r in results.items()]
    largest = max(results.values(), key=lambda r: math.hypot(r.dy, r.dx))
    worst = min(results.values(), key=lambda r: r.score)
    lines.append(
        f"{len(results)} pairs; largest shift {math.hypot(largest.dy, largest.dx):.2f} px; "
        f"lowest score {worst.score:.3f}"
    )
    return "\n".join(lines)


def _luma_pair(reference: Tensor, moving: Tensor) -> tuple[Tensor, Tensor]:
    ref = _luma(reference, "reference")
    mov = _luma(moving, "moving")
    if ref.shape != mov.shape:
        raise ValueError(
            f"reference and moving must have the same height and width, got {tuple(ref.shape)} and "
            f"{tuple(mov.shape)}; crop or resize them first"
        )
    if min(ref.shape) < _MIN_SIDE:
        raise ValueError(f"images must be at least {_MIN_SIDE}x{_MIN_SIDE} pixels, got {tuple(ref.shape)}")
    return ref, mov


def _luma(image: Tensor, name: str) -> Tensor:
    if not isinstance(image, Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(image).__name__}")
    if image.dtype != torch.uint8 and not image.is_floating_point():
        raise TypeError(f"{name} must be uint8 or floating point, got dtype {image.dtype}")
    image = image.detach().to(torch.float32)
    if image.ndim == 2:
        return image
    if image.ndim == 3 and image.shape[0] == 3:
        return luma(image)
    if image.ndim == 3 and image.shape[0] == 1:
        return image[0]
    raise ValueError(f"{name} must have shape (3, H, W), (1, H, W) or (H, W), got shape {tuple(image.shape)}")


def _estimate(ref: Tensor, mov: Tensor) -> tuple[float, float]:
    dy, dx = _correlate(ref, mov)
    # Re-measure on the overlap left by the integer part: the window then sees (nearly) the same content in both.
    for _ in range(_REFINE_ROUNDS):
        iy, ix = round(dy), round(dx)
        ref_crop, mov_crop = _overlap(ref, mov, iy, ix)
        if min(ref_crop.shape) < _MIN_SIDE:
            break
        ry, rx = _correlate(ref_crop, mov_crop)
        dy, dx = iy + ry, ix + rx
        if (round(dy), round(dx)) == (iy, ix):
            break
    return dy, dx


def _correlate(ref: Tensor, mov: Tensor) -> tuple[float, float]:
    height, width = ref.shape
    window = hann2d(height, width, ref.dtype, ref.device)
    cross = torch.fft.fft2(_standardise(mov) * window) * torch.fft.fft2(_standardise(ref) * window).conj()
    magnitude = cross.abs()
    fy = torch.fft.fftfreq(height, dtype=ref.dtype, device=ref.device)[:, None]
    fx = torch.fft.fftfreq(width, dtype=ref.dtype, device=ref.device)[None, :]
    lowpass = torch.exp(-(fy**2 + fx**2) / (2 * _LOWPASS_SIGMA**2))
    floor = 1e-6 * float(magnitude.max()) ** 0.5 + 1e-30
    spectrum = cross * (lowpass / (magnitude.sqrt() + floor))

    surface = torch.fft.ifft2(spectrum).real
    peak_y, peak_x = divmod(int(surface.argmax()), width)
    peak_y = peak_y - height if peak_y > height // 2 else peak_y
    peak_x = peak_x - width if peak_x > width // 2 else peak_x
    # Two zoom levels of the exact (band-limited) correlation surface around the integer peak: 0.1 px, then 0.01 px.
    y, x = float(peak_y), float(peak_x)
    for step, radius in ((0.1, 15), (0.01, 12)):
        y, x = _upsampled_peak(spectrum, y, x, step, radius)
    return y, x


def _upsampled_peak(spectrum: Tensor, y: float, x: float, step: float, radius: int) -> tuple[float, float]:
    """Evaluate the inverse DFT of ``spectrum`` on a fine grid around ``(y, x)`` and return its maximum."""
    height, width = spectrum.shape
    offsets = torch.arange(-radius, radius + 1, dtype=torch.float64, device=spectrum.device) * step
    ys, xs = y + offsets, x + offsets
    fy = torch.fft.fftfreq(height, dtype=torch.float64, device=spectrum.device)
    fx = torch.fft.fftfreq(width, dtype=torch.float64, device=spectrum.device)
    # Phases in float64 (they reach pi * size radians), then cast to the spectrum's precision.
    rows = torch.exp(2j * math.pi * ys[:, None] * fy[None, :]).to(spectrum.dtype)
    cols = torch.exp(2j * math.pi * fx[:, None] * xs[None, :]).to(spectrum.dtype)
    fine = (rows @ spectrum @ cols).real
    best_y, best_x = divmod(int(fine.argmax()), fine.shape[1])
    return float(ys[best_y]), float(xs[best_x])


def _aligned_correlation(ref: Tensor, mov: Tensor, dy: float, dx: float) -> float:
    iy, ix = round(dy), round(dx)
    ref_crop, mov_crop = _overlap(ref, mov, iy, ix)
    if min(ref_crop.shape) < 2:
        return 0.0
    mov_crop = apply_shift(mov_crop, -(dy - iy), -(dx - ix))
    margin = 2  # the fractional shift leaves one mirrored row/column at the borders
    if min(ref_crop.shape) > 4 * margin:
        ref_crop = ref_crop[margin:-margin, margin:-margin]
        mov_crop = mov_crop[margin:-margin, margin:-margin]
    a, b = _standardise(ref_crop), _standardise(mov_crop)
    return float((a * b).mean().clamp(-1.0, 1.0))


def _overlap(ref: Tensor, mov: Tensor, iy: int, ix: int) -> tuple[Tensor, Tensor]:
    """Crops of ``ref`` and ``mov`` showing the same content when ``mov`` is ``ref`` moved by ``(iy, ix)``."""
    height, width = ref.shape
    ref_crop = ref[max(0, -iy) : height - max(0, iy), max(0, -ix) : width - max(0, ix)]
    mov_crop = mov[max(0, iy) : height - max(0, -iy), max(0, ix) : width - max(0, -ix)]
    return ref_crop, mov_crop


def _valid_span(shift: float, size: int) -> slice:
    """Rows (or columns) of an image moved by ``shift`` that were filled from real source pixels."""
    lost = math.ceil(abs(shift) - 1e-6)
    return slice(lost, size) if shift > 0 else slice(0, size - lost)


def _standardise(image: Tensor) -> Tensor:
    centred = image - image.mean()
    return centred / (centred.std() + 1e-12)


def _phase_ramp(height: int, width: int, dy: float, dx: float, device: torch.device) -> Tensor:
    fy = torch.fft.fftfreq(height, dtype=torch.float64, device=device)[:, None]
    fx = torch.fft.fftfreq(width, dtype=torch.float64, device=device)[None, :]
    return torch.exp(-2j * math.pi * (fy * dy + fx * dx))
