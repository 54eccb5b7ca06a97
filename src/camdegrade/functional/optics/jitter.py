"""Kernels of a random local displacement (jitter): a smooth field of sub-pixel shifts, and the image read at the
shifted positions."""

from __future__ import annotations

import math
from functools import lru_cache

import torch
import torch.nn.functional as F
from torch import Tensor

__all__ = [
    "NODES_PER_SCALE",
    "compensation_taps",
    "displacement_field",
    "field_at",
    "field_grid",
    "gaussian_taps",
    "interpolation_power",
    "jitter_image",
]

#: The cubic convolution kernel's parameter in torch's bicubic ``grid_sample`` (Keys' ``a``).
CUBIC_A = -0.75
#: Taps of the pre-emphasis that undoes the interpolation's mean loss of power (:func:`compensation_taps`).
COMPENSATION_TAPS = 7


def gaussian_taps(scale: float, dtype: torch.dtype = torch.float32, device: torch.device | None = None) -> Tensor:
    """The normalised 1-D Gaussian of standard deviation ``scale`` pixels, ``2·ceil(3·scale) + 1`` taps."""
    reach = max(1, math.ceil(3 * scale))
    offsets = torch.arange(-reach, reach + 1, dtype=torch.float64)
    taps = torch.exp(-0.5 * (offsets / scale) ** 2)
    return (taps / taps.sum()).to(dtype=dtype, device=device)


#: The field is drawn on a grid this many nodes per correlation length and brought to full size bilinearly: a field
#: that smooth loses nothing between nodes (its spectrum at their Nyquist frequency is e^-20), and the smoothing
#: costs a sixteenth of a full-size one.
NODES_PER_SCALE = 2


def field_grid(height: int, width: int, scale: float) -> tuple[int, int]:
    """The node grid ``(rows, columns)`` of a field of correlation length ``scale`` over an ``height × width``
    frame: nodes at most ``scale / NODES_PER_SCALE`` pixels apart, at least 2 a side."""
    step = scale / NODES_PER_SCALE
    return tuple(max(2, math.ceil((size - 1) / step) + 1) for size in (height, width))  # type: ignore[return-value]


def displacement_field(normal: Tensor, sigma: Tensor | float, scale: float, size: tuple[int, int]) -> Tensor:
    """``(N, 2, H, W)`` shifts in pixels (rows, columns) of root-mean-square ``sigma`` per axis over a frame of
    ``size = (H, W)``: white ``normal`` ``(N, 2, rows, columns)`` on :func:`field_grid`'s nodes, smoothed by a
    Gaussian of :data:`NODES_PER_SCALE` nodes (``scale`` pixels; reflected at the edges), scaled by the smoothing's
    known variance (``(Σ taps²)²``, so the RMS does not depend on the draw) and brought to full size bilinearly."""
    taps = gaussian_taps(NODES_PER_SCALE, normal.dtype, normal.device)
    reach = (len(taps) - 1) // 2
    rows, columns = normal.shape[-2:]
    pad = min(reach, rows - 1, columns - 1)
    field = F.pad(normal, (pad, pad, pad, pad), mode="reflect")
    if pad < reach:  # a grid smaller than the kernel: zeros beyond one reflection
        field = F.pad(field, (reach - pad,) * 4)
    field = F.conv2d(field, taps.view(1, 1, 1, -1).expand(2, 1, 1, -1), groups=2)
    field = F.conv2d(field, taps.view(1, 1, -1, 1).expand(2, 1, -1, 1), groups=2)
    field = F.interpolate(field, size=tuple(size), mode="bilinear", align_corners=True)
    return field * (torch.as_tensor(sigma, dtype=normal.dtype, device=normal.device) / taps.pow(2).sum())


def _cubic(x: Tensor) -> Tensor:
    x = x.abs()
    near = (CUBIC_A + 2) * x**3 - (CUBIC_A + 3) * x**2 + 1
    far = CUBIC_A * (x**3 - 5 * x**2 + 8 * x - 4)
    return torch.where(x <= 1, near, torch.where(x < 2, far, torch.zeros_like(x)))


def interpolation_power(sigma: float, frequencies: Tensor) -> Tensor:
    """Per axis, the mean power gain ``E|h_t(f)|²`` of cubic interpolation at ``frequencies`` (cycles/pixel) over
    the fractional positions ``t`` a Gaussian shift of ``sigma`` pixels reads at: 1 at whole pixels, 0 at
    half-pixel positions at 0.5 cycles/pixel."""
    shifts = torch.linspace(-5 * sigma, 5 * sigma, 2001, dtype=torch.float64)
    weights = torch.exp(-0.5 * (shifts / sigma) ** 2)
    fraction = (shifts - shifts.floor())[:, None]
    offsets = torch.tensor([-1.0, 0.0, 1.0, 2.0], dtype=torch.float64)[None]
    taps = _cubic(offsets - fraction)  # (shifts, 4)
    phase = torch.exp(-2j * math.pi * frequencies.double()[None, None] * (offsets - fraction)[..., None])
    response = (taps[..., None] * phase).sum(1)
    return (weights[:, None] * response.abs() ** 2).sum(0) / weights.sum()


@lru_cache(maxsize=64)
def compensation_taps(sigma: float) -> tuple[float, ...]:
    """A symmetric FIR of :data:`COMPENSATION_TAPS` taps whose gain is ``interpolation_power(sigma)^(−1/2)`` over
    0–0.5 cycles/pixel (least squares): applied before the shift, the jittered image keeps its power spectrum (a
    displacement moves detail, it does not blur it)."""
    frequencies = torch.linspace(0, 0.5, 65, dtype=torch.float64)
    target = interpolation_power(sigma, frequencies).clamp_min(0.25).rsqrt()
    half = COMPENSATION_TAPS // 2
    basis = torch.stack(
        [torch.ones_like(frequencies)] + [2 * torch.cos(2 * math.pi * k * frequencies) for k in range(1, half + 1)], 1
    )
    coefficients = torch.linalg.lstsq(basis, target[:, None]).solution[:, 0]
    return tuple(float(c) for c in (*coefficients[1:].flip(0), coefficients[0], *coefficients[1:]))


def jitter_image(image: Tensor, field: Tensor, sigma: float) -> Tensor:
    """``image`` ``(N, C, H, W)`` read at each pixel's position plus its shift in ``field`` ``(N, 2, H, W)``
    (bicubic; the frame's edge extended), after the pre-emphasis of :func:`compensation_taps` for shifts of
    ``sigma`` pixels per axis."""
    taps = torch.tensor(compensation_taps(round(float(sigma), 4)), dtype=image.dtype, device=image.device)
    reach = len(taps) // 2
    channels = image.shape[1]
    if min(image.shape[-2:]) > reach:
        padded = F.pad(image, (reach, reach, reach, reach), mode="replicate")
        padded = F.conv2d(padded, taps.view(1, 1, 1, -1).expand(channels, 1, 1, -1), groups=channels)
        image = F.conv2d(padded, taps.view(1, 1, -1, 1).expand(channels, 1, -1, 1), groups=channels)
    _, _, height, width = image.shape
    rows = torch.arange(height, dtype=image.dtype, device=image.device)[:, None] + field[:, 0]
    columns = torch.arange(width, dtype=image.dtype, device=image.device)[None, :] + field[:, 1]
    grid = torch.stack([columns * (2 / max(width - 1, 1)) - 1, rows * (2 / max(height - 1, 1)) - 1], -1)
    return F.grid_sample(image, grid, mode="bicubic", padding_mode="border", align_corners=True)


def field_at(field: Tensor, x: Tensor, y: Tensor) -> Tensor:
    """``(N, 2, P)``: the shifts of ``field`` ``(N, 2, H, W)`` (bilinear) at the centred positions ``(x, y)``
    ``(N, P)`` or ``(1, P)`` (pixels from the frame's centre, x right, y down), the frame's edge extended."""
    height, width = field.shape[-2:]
    columns = (x + width / 2 - 0.5) * (2 / max(width - 1, 1)) - 1
    rows = (y + height / 2 - 0.5) * (2 / max(height - 1, 1)) - 1
    grid = torch.stack([columns, rows], -1).to(field.dtype).expand(field.shape[0], -1, -1)[:, None]
    return F.grid_sample(field, grid, mode="bilinear", padding_mode="border", align_corners=True)[:, :, 0]
