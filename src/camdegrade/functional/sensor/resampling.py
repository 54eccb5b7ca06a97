"""Separable resampling by a named kernel (the resizers image libraries and ISPs use), as two matrix products.

Output pixel ``i`` of ``n_out`` is centred at ``(i + 0.5) · n_in / n_out − 0.5`` in input pixels; it is the
kernel-weighted mean of the input pixels within the kernel's support, the support widened by ``n_in / n_out`` when
reducing (antialiasing), cut at the image's edges and normalised to sum to 1.
``nearest`` takes the input pixel under the centre. Lanczos is the 3-lobe one; ``catmull_rom`` is Keys' cubic with
``a = −0.5`` (PIL's and OpenCV's "bicubic"); ``bicubic`` here is ``a = −0.75`` (torch's and camdegrade's
``resolution`` stage's).

References:
    R. Keys, "Cubic convolution interpolation for digital image processing", IEEE TASSP 29(6), 1981; C. E. Duchon,
    "Lanczos filtering in one and two dimensions", J. Applied Meteorology 18(8), 1979.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from torch import Tensor

from camdegrade.functional._utils import apply_float, check_image

__all__ = ["KERNELS", "resample_matrix", "resize_image"]


def _box(x: Tensor) -> Tensor:
    return ((x >= -0.5) & (x < 0.5)).to(x.dtype)


def _triangle(x: Tensor) -> Tensor:
    return (1 - x.abs()).clamp_min(0)


def _keys(a: float) -> Callable[[Tensor], Tensor]:
    def cubic(x: Tensor) -> Tensor:
        t = x.abs()
        near = ((a + 2) * t - (a + 3)) * t * t + 1
        far = ((a * t - 5 * a) * t + 8 * a) * t - 4 * a
        return torch.where(t < 1, near, torch.where(t < 2, far, torch.zeros_like(t)))

    return cubic


def _lanczos3(x: Tensor) -> Tensor:
    return torch.where(x.abs() < 3, torch.sinc(x) * torch.sinc(x / 3), torch.zeros_like(x))


#: kernel name → (weight function, support radius in input pixels at unit scale).
KERNELS: dict[str, tuple[Callable[[Tensor], Tensor], float]] = {
    "box": (_box, 0.5),
    "bilinear": (_triangle, 1.0),
    "bicubic": (_keys(-0.75), 2.0),
    "catmull_rom": (_keys(-0.5), 2.0),
    "lanczos": (_lanczos3, 3.0),
}


def resample_matrix(n_in: int, n_out: int, kernel: str, dtype: torch.dtype = torch.float64) -> Tensor:
    """``(n_out, n_in)``: the weights of each output pixel on the input pixels (rows sum to 1)."""
    centre = (torch.arange(n_out, dtype=torch.float64) + 0.5) * n_in / n_out - 0.5
    if kernel == "nearest":
        index = (centre + 0.5).floor().long().clamp(0, n_in - 1)
        return torch.nn.functional.one_hot(index, n_in).to(dtype)
    if kernel not in KERNELS:
        raise ValueError(f"kernel must be one of {('nearest', *KERNELS)}, got kernel={kernel!r}")
    weight, support = KERNELS[kernel]
    stretch = max(n_in / n_out, 1.0)
    reach = math.ceil(support * stretch) + 1
    taps = centre.floor().long()[:, None] + torch.arange(-reach + 1, reach + 1)
    inside = (taps >= 0) & (taps < n_in)
    weights = weight((taps - centre[:, None]) / stretch) * inside
    weights = weights / weights.sum(1, keepdim=True)
    matrix = torch.zeros(n_out, n_in, dtype=torch.float64)
    matrix.scatter_add_(1, taps.clamp(0, n_in - 1), weights)
    return matrix.to(dtype)


def resize_image(image: Tensor, size: tuple[int, int], kernel: str) -> Tensor:
    """``image`` (``[..., 3, H, W]`` uint8 or float in [0, 1]) resized to ``size = (rows, columns)`` by ``kernel``
    (``nearest`` or one of :data:`KERNELS`), clipped to [0, 1].

    Examples:
        >>> image = torch.rand(1, 3, 8, 8, generator=torch.Generator().manual_seed(0))
        >>> resize_image(image, (16, 12), "lanczos").shape
        torch.Size([1, 3, 16, 12])
    """
    check_image(image)
    height, width = image.shape[-2:]

    def kernel_fn(x: Tensor) -> Tensor:
        rows = resample_matrix(height, size[0], kernel, x.dtype).to(x.device)
        columns = resample_matrix(width, size[1], kernel, x.dtype).to(x.device)
        return (rows @ x @ columns.T).clamp(0.0, 1.0)

    return apply_float(image, kernel_fn)
