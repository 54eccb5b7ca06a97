"""Linear filtering of float planes ``(..., H, W)``, the kernels a composed chain of filters runs on: sums of separable
terms (shifted sums, the border mirrored) and products of spectra (the border mirrored, then the FFT).

References:
    R. C. Gonzalez, R. E. Woods, "Digital Image Processing", 4th ed., 2018, ch. 3–4 (separable spatial filtering;
    filtering in the frequency domain, padding against wrap-around).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch
import torch.nn.functional as F
from torch import Tensor

from camdegrade.functional._utils import one_plane_at_a_time
from camdegrade.functional.analysis.images import LUMA_WEIGHTS

__all__ = ["SeparableTerm", "convolve_spectrum", "convolve_terms", "luma_plane", "terms_radius"]

#: One separable term of a kernel: its weight, its taps down (rows) and across (columns), odd counts, centred.
SeparableTerm = tuple[float, tuple[float, ...], tuple[float, ...]]


def luma_plane(image: Tensor) -> Tensor:
    """``[..., 3, H, W]`` → ``[..., 1, H, W]``: the Rec. 601 luma, by two fused additions on one plane."""
    (red, green, blue), (wr, wg, wb) = image.unbind(-3), LUMA_WEIGHTS
    return (red * wr).add_(green, alpha=wg).add_(blue, alpha=wb).unsqueeze(-3)


def terms_radius(terms: Sequence[SeparableTerm]) -> tuple[int, int]:
    """The largest half-length of the ``terms``' taps down and across."""
    return max((len(down) // 2 for _, down, _ in terms), default=0), max(
        (len(across) // 2 for _, _, across in terms), default=0
    )


def convolve_terms(planes: Tensor, identity: float, terms: Sequence[SeparableTerm]) -> Tensor:
    """``identity · planes + Σ weight · (down ⊗ across) ⊛ planes`` for float ``planes`` ``(N, C, H, W)`` (a new
    tensor): the border mirrored once for all terms (``reflect``: every radius must be below H and W), each term one
    pass of shifted sums across and one down, added straight into the result (Python-float weights, so every step is
    one fused multiply-add)."""
    height, width = planes.shape[-2:]
    rows_radius, cols_radius = terms_radius(terms)
    padded = planes
    if rows_radius or cols_radius:
        padded = F.pad(planes, (cols_radius, cols_radius, rows_radius, rows_radius), mode="reflect")
    total = planes * identity if identity else None
    for weight, down, across in terms:
        radius_down, radius_across = len(down) // 2, len(across) // 2
        rows = padded[..., rows_radius - radius_down : rows_radius + height + radius_down, :]
        start = cols_radius - radius_across
        filtered = rows[..., start : start + width] * across[0]
        for index in range(1, len(across)):
            filtered.add_(rows[..., start + index : start + index + width], alpha=across[index])
        for index, tap in enumerate(down):
            shifted = filtered[..., index : index + height, :]
            if total is None:
                total = shifted * (weight * tap)
            else:
                total.add_(shifted, alpha=weight * tap)
    return planes.mul(0.0) if total is None else total


def convolve_spectrum(planes: Tensor, gains_of: Callable[[int, int], Tensor], pad: int) -> Tensor:
    """Float ``planes`` ``(N, C, H, W)`` filtered by the transfer ``gains_of(h, w)`` (the gain of every ``rfft2``
    frequency of an ``h × w`` frame, in the planes' complex dtype and device) of the planes with ``pad`` rows and
    columns of mirrored border on each side (at most ``H − 1`` and ``W − 1``): a new tensor."""
    if planes.numel() == 0:  # an FFT of no planes is an error in MKL
        return planes.clone()
    height, width = planes.shape[-2:]
    padded = F.pad(planes, (pad, pad, pad, pad), mode="reflect") if pad > 0 else planes
    size = padded.shape[-2:]
    gains = gains_of(*size)
    filtered = one_plane_at_a_time(lambda plane: torch.fft.irfft2(torch.fft.rfft2(plane) * gains, s=size), padded)
    return filtered[..., pad : pad + height, pad : pad + width]
