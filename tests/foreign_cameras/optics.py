"""Lens and geometry: point-spread functions (defocus disc, a Gaussian-like lens with a halo, linear motion),
their convolution, vignetting (the cos⁴ law and a polynomial falloff) and a sub-pixel misalignment by a resampler.

References: Goodman, *Introduction to Fourier Optics* (defocus as a uniform disc in the geometric limit);
Ray, *Applied Photographic Optics* (natural vignetting, the cos⁴ law).
"""

from __future__ import annotations

import numpy as np
from PIL import Image
from scipy import ndimage

#: Sub-samples per pixel side when a PSF is rasterised (anti-aliased edges).
_SUBSAMPLES = 8


def disc_psf(radius: float) -> np.ndarray:
    """A uniform disc of ``radius`` pixels (defocus in the geometric limit), each pixel weighted by the share of it
    the disc covers (sampled on an 8×8 sub-grid); sums to 1."""
    half = int(np.ceil(radius))
    offsets = (np.arange(_SUBSAMPLES) + 0.5) / _SUBSAMPLES - 0.5
    grid = np.arange(-half, half + 1)
    fine = (grid[:, None] + offsets[None, :]).ravel()
    inside = (fine[:, None] ** 2 + fine[None, :] ** 2) <= radius**2
    side = 2 * half + 1
    psf = inside.reshape(side, _SUBSAMPLES, side, _SUBSAMPLES).mean(axis=(1, 3))
    return psf / psf.sum()


def lens_psf(sigma: float, halo_sigma: float = 0.0, halo_weight: float = 0.0) -> np.ndarray:
    """A Gaussian core of ``sigma`` pixels plus a wide Gaussian halo (veiling flare, ``halo_weight`` of the
    energy): the shape of a real lens's PSF is closer to this than to one Gaussian. Sums to 1."""
    half = int(np.ceil(3.0 * max(sigma, halo_sigma)))
    grid = np.arange(-half, half + 1, dtype=np.float64)
    radius2 = grid[:, None] ** 2 + grid[None, :] ** 2
    psf = np.exp(-radius2 / (2.0 * sigma**2))
    psf /= psf.sum()
    if halo_weight > 0.0:
        halo = np.exp(-radius2 / (2.0 * halo_sigma**2))
        psf = (1.0 - halo_weight) * psf + halo_weight * halo / halo.sum()
    return psf / psf.sum()


def motion_psf(length: float, angle_degrees: float) -> np.ndarray:
    """A straight motion streak of ``length`` pixels at ``angle_degrees`` (counter-clockwise from the x axis):
    points along the segment splatted bilinearly onto the grid. Sums to 1."""
    half = int(np.ceil(length / 2.0)) + 1
    side = 2 * half + 1
    psf = np.zeros((side, side))
    angle = np.deg2rad(angle_degrees)
    for t in np.linspace(-length / 2.0, length / 2.0, int(length * _SUBSAMPLES) + 1):
        x, y = half + t * np.cos(angle), half - t * np.sin(angle)
        x0, y0 = int(np.floor(x)), int(np.floor(y))
        fx, fy = x - x0, y - y0
        psf[y0, x0] += (1 - fx) * (1 - fy)
        psf[y0, x0 + 1] += fx * (1 - fy)
        psf[y0 + 1, x0] += (1 - fx) * fy
        psf[y0 + 1, x0 + 1] += fx * fy
    return psf / psf.sum()


def convolve(x: np.ndarray, psf: np.ndarray) -> np.ndarray:
    """Each channel of ``x`` (H, W, C) convolved with ``psf``, the border mirrored (whole-sample symmetric)."""
    return np.stack([ndimage.convolve(x[..., c], psf, mode="mirror") for c in range(x.shape[-1])], axis=-1)


def _radius(height: int, width: int) -> np.ndarray:
    """Distance of each pixel centre from the frame centre, 1 at the corners."""
    y = (np.arange(height) + 0.5 - height / 2.0) / (height / 2.0)
    x = (np.arange(width) + 0.5 - width / 2.0) / (width / 2.0)
    return np.sqrt(y[:, None] ** 2 + x[None, :] ** 2) / np.sqrt(2.0)


def cos4_falloff(height: int, width: int, corner_angle_degrees: float) -> np.ndarray:
    """The natural vignetting of a thin lens: ``cos⁴ θ``, θ the field angle, ``corner_angle_degrees`` at the
    corners (a wide lens: 35°, corners at 0.45)."""
    tangent = _radius(height, width) * np.tan(np.deg2rad(corner_angle_degrees))
    return np.cos(np.arctan(tangent)) ** 4


def polynomial_falloff(height: int, width: int, k1: float, k2: float = 0.0) -> np.ndarray:
    """A polynomial falloff ``1 + k1 r² + k2 r⁴`` (r 1 at the corners): mechanical vignetting of a lens hood or a
    small aperture stop, as lens-correction tables model it."""
    radius2 = _radius(height, width) ** 2
    return 1.0 + k1 * radius2 + k2 * radius2**2


def misalign(x: np.ndarray, dx: float, dy: float, angle_degrees: float, resample: Image.Resampling) -> np.ndarray:
    """``x`` (H, W, C) moved by (``dx``, ``dy``) pixels and rotated by ``angle_degrees`` about the frame centre,
    resampled by PIL (each channel a float image); the border is mirrored first so that no fill colour comes in."""
    height, width = x.shape[:2]
    pad = 8
    padded = np.pad(x, ((pad, pad), (pad, pad), (0, 0)), mode="symmetric")
    angle = np.deg2rad(angle_degrees)
    cos, sin = np.cos(angle), np.sin(angle)
    cy, cx = padded.shape[0] / 2.0, padded.shape[1] / 2.0
    # PIL's affine maps each output pixel (u, v) to the input point (a u + b v + c, d u + e v + f).
    a, b, d, e = cos, sin, -sin, cos
    c = cx - a * (cx + dx) - b * (cy + dy)
    f = cy - d * (cx + dx) - e * (cy + dy)
    size = (padded.shape[1], padded.shape[0])
    planes = [
        np.asarray(
            Image.fromarray(padded[..., k].astype(np.float32)).transform(
                size, Image.Transform.AFFINE, (a, b, c, d, e, f), resample=resample
            ),
            dtype=np.float64,
        )
        for k in range(x.shape[-1])
    ]
    return np.stack(planes, axis=-1)[pad : pad + height, pad : pad + width]
