"""Kernel of a camera's luma frequency response: a gain per spatial frequency, applied in the Fourier domain.

The gains sit on a grid of ``K × K`` knots over ``(|f_y|, |f_x|)`` from 0 to 0.5 cycles/pixel (so a response can
differ along the axes and the diagonals, as a demosaicker's and a sharpener's do) and are interpolated bilinearly
between them. The response filters the Rec. 601 luma; what it changes is added to R, G and B alike, so it leaves
the colour alone, as a phone's detail processing does.

References:
    R. C. Gonzalez, R. E. Woods, "Digital Image Processing", 4th ed., 2018, ch. 4 (filtering in the frequency
    domain; padding against wrap-around).
"""

from __future__ import annotations

import functools
from collections import OrderedDict

import torch
from torch import Tensor

from camdegrade.functional._utils import apply_float, check_image
from camdegrade.functional.analysis.images import luma as luma_of
from camdegrade.functional.filtering import convolve_spectrum

__all__ = [
    "MAPS_KEPT",
    "PAD",
    "cached_response_map",
    "filter_planes",
    "frequency_response_image",
    "knot_coordinates",
    "response_map",
]

#: Rows and columns of mirrored border added on each side before the FFT, so that the filter's wrap-around reads a
#: reflection of the image rather than its opposite edge (the fitted responses' kernels are a few pixels wide).
PAD = 16


def knot_coordinates(size: int, knots: int, *, half: bool, device: torch.device | None = None) -> Tensor:
    """Each frequency of an FFT of ``size`` samples (``rfftfreq`` with ``half``, else ``|fftfreq|``) in knot units:
    0 at 0 cycles/pixel, ``knots − 1`` at 0.5."""
    frequency = torch.fft.rfftfreq(size, device=device) if half else torch.fft.fftfreq(size, device=device).abs()
    return frequency * (2 * (knots - 1))


def response_map(gains: Tensor, height: int, width: int) -> Tensor:
    """``(height, width // 2 + 1)``: the gain of every ``rfft2`` frequency of a ``height × width`` image, from the
    ``(K, K)`` knot ``gains`` over ``(|f_y|, |f_x|)``, interpolated bilinearly."""
    knots = gains.shape[-1]
    rows = knot_coordinates(height, knots, half=False, device=gains.device)
    cols = knot_coordinates(width, knots, half=True, device=gains.device)
    top, left = rows.floor().long().clamp(max=knots - 2), cols.floor().long().clamp(max=knots - 2)
    down, right = (rows - top)[:, None], (cols - left)[None, :]
    above, below = gains[top], gains[top + 1]
    upper = above[:, left] * (1 - right) + above[:, left + 1] * right
    lower = below[:, left] * (1 - right) + below[:, left + 1] * right
    return upper * (1 - down) + lower * down


#: Response maps kept, the most recently used last: building one is about a third of the stage's time on a 224²
#: image (0.34 of 0.93 ms, AMD EPYC, 2 threads), and a transform sees few gains and sizes.
MAPS_KEPT = 8

_maps: OrderedDict[tuple, Tensor] = OrderedDict()


def cached_response_map(gains: Tensor, height: int, width: int, dtype: torch.dtype) -> Tensor:
    """:func:`response_map` of ``gains`` in ``dtype``, kept for the :data:`MAPS_KEPT` most recent (gains, size,
    dtype, device). Keyed by the gains' values, so a change to them made any way (in place, through ``.data``,
    through NumPy) is seen; gains that need a gradient are never cached."""
    if gains.requires_grad:
        return response_map(gains.to(dtype), height, width)
    values = gains.detach().to("cpu", torch.float64).numpy().tobytes()
    key = (values, tuple(gains.shape), height, width, dtype, str(gains.device))
    if key in _maps:
        _maps.move_to_end(key)
        return _maps[key]
    mapped = response_map(gains.to(dtype), height, width)
    _maps[key] = mapped
    if len(_maps) > MAPS_KEPT:
        _maps.popitem(last=False)
    return mapped


def filter_planes(planes: Tensor, gains: Tensor) -> Tensor:
    """Float ``(..., H, W)`` planes filtered by the response ``gains`` (mirrored borders of :data:`PAD` pixels, or
    fewer where a plane is smaller)."""
    height, width = planes.shape[-2:]
    flat = planes.reshape(planes.shape[:-2].numel(), 1, height, width)  # -1 is ambiguous for no pixels
    response = functools.partial(cached_response_map, gains, dtype=flat.dtype)
    return convolve_spectrum(flat, response, min(PAD, height - 1, width - 1)).reshape(planes.shape)


def frequency_response_image(image: Tensor, gains: Tensor) -> Tensor:
    """``clip(x + (R ⊛ Y − Y), 0, 1)``: the luma ``Y`` of the sRGB values ``x`` filtered by the response ``R`` of the
    ``(K, K)`` knot ``gains`` (all ones: the identity), the change added to R, G and B alike.

    Args:
        image: ``[..., 3, H, W]`` uint8 or float in [0, 1].
        gains: ``(K, K)`` amplitude gains, ``K ≥ 2``, at ``(|f_y|, |f_x|) = (i, j) · 0.5 / (K − 1)`` cycles/pixel.

    Examples:
        >>> image = torch.rand(2, 3, 32, 32, generator=torch.Generator().manual_seed(0))
        >>> bool((frequency_response_image(image, torch.ones(11, 11)) - image).abs().max() < 1e-5)
        True
    """
    check_image(image)
    if gains.ndim != 2 or gains.shape[0] != gains.shape[1] or gains.shape[0] < 2:
        raise ValueError(f"gains must be a square (K, K) grid with K >= 2, got shape {tuple(gains.shape)}")

    def kernel(x: Tensor) -> Tensor:
        gray = luma_of(x.float())
        change = filter_planes(gray, gains.to(device=x.device, dtype=torch.float32)) - gray
        return (x + change.to(x.dtype).unsqueeze(-3)).clamp(0.0, 1.0)

    return apply_float(image, kernel)
