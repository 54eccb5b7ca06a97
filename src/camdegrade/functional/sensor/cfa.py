"""Colour filter array kernel: a Bayer mosaic of the image in linear light, demosaiced bilinearly or edge-directed.

A Bayer sensor records one colour per site (a 2×2 tile of red, two greens and blue, in one of four layouts); the
ISP interpolates the two missing colours at every site. Bilinear demosaicing takes the mean of the nearest sites of
that colour: green from the 4 edge neighbours at a red or blue site, red and blue from the 2 neighbours at a green
site and from the 4 diagonal ones at the other colour's site. What it leaves: colour fringes at edges, a softer image
and, in the error to the scene, a 2×2 phase pattern (nothing at the sites a colour is sampled at:
:func:`phase_error`); in the image alone, colours interpolated from their neighbours are smooth where they were not
sampled (:func:`interpolation_phases`). Both are read against red and blue (:func:`colour_phase_share`): a mosaic
samples them at different phases, where a resampler, a JPEG grid or a sensor's readout leaves one phase pattern in
every channel.

References:
    B. E. Bayer, "Color imaging array", US patent 3,971,065, 1976; B. K. Gunturk et al., "Demosaicking: color
    filter array interpolation", IEEE Signal Processing Magazine 22(1), 2005.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from camdegrade.functional._utils import apply_float, check_image
from camdegrade.functional.isp.color import linear_to_srgb, srgb_to_linear
from camdegrade.functional.sensor.edge_demosaic import edge_directed_demosaic

__all__ = [
    "PATTERNS",
    "bayer_masks",
    "colour_phase_share",
    "demosaic_image",
    "interpolation_phases",
    "luma_phases",
    "phase_error",
]

#: Bayer layouts: the colour (0 red, 1 green, 2 blue) of the sites (0, 0), (0, 1), (1, 0), (1, 1).
PATTERNS: dict[str, tuple[int, int, int, int]] = {
    "RGGB": (0, 1, 1, 2),
    "GRBG": (1, 0, 2, 1),
    "GBRG": (1, 2, 0, 1),
    "BGGR": (2, 1, 1, 0),
}
#: Demosaicing methods: bilinear (each missing colour the mean of its nearest sites of that colour) and edge
#: (edge-directed green, bilinear colour differences: :mod:`camdegrade.functional.sensor.edge_demosaic`).
DEMOSAICS: tuple[str, ...] = ("bilinear", "edge")
#: Neighbour weights: green (4 edge neighbours), red and blue (edge and diagonal), the site itself 1.
_GREEN = torch.tensor([[0.0, 0.25, 0.0], [0.25, 1.0, 0.25], [0.0, 0.25, 0.0]])
_RED_BLUE = torch.tensor([[0.25, 0.5, 0.25], [0.5, 1.0, 0.5], [0.25, 0.5, 0.25]])


def bayer_masks(height: int, width: int, pattern: str) -> Tensor:
    """``(3, H, W)`` float: 1 where the sensor samples that colour."""
    if pattern not in PATTERNS:
        raise ValueError(f"pattern must be one of {tuple(PATTERNS)}, got pattern={pattern!r}")
    tile = torch.tensor(PATTERNS[pattern]).reshape(2, 2)
    colours = tile.repeat((height + 1) // 2, (width + 1) // 2)[:height, :width]
    return (colours[None] == torch.arange(3)[:, None, None]).float()


def demosaic_image(image: Tensor, pattern: str = "RGGB", method: str = "bilinear") -> Tensor:
    """``image`` (``[..., 3, H, W]`` sRGB, uint8 or float in [0, 1], H and W at least 2; 3 for ``edge``) sampled by
    a Bayer sensor of ``pattern`` in linear light and demosaiced by ``method`` (one of :data:`DEMOSAICS`:
    ``bilinear``, or ``edge``: :func:`~camdegrade.functional.sensor.edge_demosaic.edge_directed_demosaic`), the
    borders mirrored, which keeps the layout's phase; the sampled value of each site is kept exactly."""
    check_image(image)
    if method not in DEMOSAICS:
        raise ValueError(f"method must be one of {DEMOSAICS}, got method={method!r}")
    height, width = image.shape[-2:]
    masks = bayer_masks(height, width, pattern)
    smallest = 2 if method == "bilinear" else 3
    if min(height, width) < smallest:
        raise ValueError(f"image must be at least {smallest}x{smallest} pixels, got {height}x{width}")

    def kernel(x: Tensor) -> Tensor:
        flat = srgb_to_linear(x.reshape(-1, 3, height, width))
        out = _bilinear(flat, masks) if method == "bilinear" else edge_directed_demosaic(flat, masks)
        return linear_to_srgb(out.clamp(0.0, 1.0)).reshape(x.shape)

    return apply_float(image, kernel)


def _bilinear(flat: Tensor, masks: Tensor) -> Tensor:
    """``flat`` (``(N, 3, H, W)``, linear) sampled by ``masks`` and demosaiced bilinearly."""
    known = masks.to(flat)
    weights = torch.stack([_RED_BLUE, _GREEN, _RED_BLUE])[:, None].to(flat)
    summed = F.conv2d(F.pad(flat * known, (1, 1, 1, 1), mode="reflect"), weights, groups=3)
    count = F.conv2d(F.pad(known[None], (1, 1, 1, 1), mode="reflect"), weights, groups=3)
    return torch.where(known > 0, flat, summed / count)


def phase_error(image: Tensor, reference: Tensor) -> Tensor:
    """``(3, 2, 2)``: the mean squared difference of ``image`` and ``reference`` (``(3, H, W)``, same scale) at each
    phase of the 2×2 grid, per channel, over its mean. A Bayer camera's error to the scene vanishes at the phases
    where that colour is sampled (red: one phase of four; green: two on a diagonal), where a blur or noise leaves
    all four alike (1)."""
    squared = (image.double() - reference.double()).pow(2)
    height, width = squared.shape[-2:] if squared.ndim == 3 else (0, 0)
    if squared.ndim != 3 or squared.shape[0] != 3 or min(height, width) < 2:
        raise ValueError(f"image must be (3, H, W) with H, W >= 2, got shape {tuple(image.shape)}")
    squared = squared[:, : height // 2 * 2, : width // 2 * 2]
    phases = squared.reshape(3, height // 2, 2, width // 2, 2).mean((1, 3))
    return phases / phases.mean((1, 2), keepdim=True).clamp_min(1e-20)


def interpolation_phases(image: Tensor) -> Tensor:
    """``(3, 2, 2)``: for red less green, green, and blue less green of ``image`` (``(3, H, W)``), the energy of its
    difference to the mean of its 4 edge neighbours at each phase of the 2×2 grid, over its mean. A demosaic
    interpolates each missing colour (an edge-directed one, the colour differences) from the sites where it was
    sampled, so there it holds the energy and elsewhere it is nearly the mean of its neighbours (bilinear: exactly, in
    linear light); noise drawn per site before the demosaic does the same. An image without a mosaic has every phase
    alike (1). Needs no reference: it reads clean images and captures alike. A mosaic of a layout reads above 1 in
    :func:`colour_phase_share` for it (where :func:`phase_error` reads below)."""
    x = _checked(image)
    return _neighbour_phases(torch.stack([x[0] - x[1], x[1], x[2] - x[1]]))


def luma_phases(image: Tensor) -> Tensor:
    """``(2, 2)``: :func:`interpolation_phases` of the luma of ``image`` (``(3, H, W)``; JPEG's weights 0.299, 0.587,
    0.114). What a JPEG with 4:2:0 chroma keeps of a mosaic (it averages red and blue less luma over each 2×2 tile):
    at the site where the sensor sampled blue, luma holds 0.114 of a sampled colour, at red's 0.299, at green's
    0.587, so a mosaic orders the phases green > red > blue."""
    x = _checked(image)
    return _neighbour_phases((0.299 * x[0] + 0.587 * x[1] + 0.114 * x[2])[None])[0]


def _checked(image: Tensor) -> Tensor:
    if image.ndim != 3 or image.shape[0] != 3 or min(image.shape[-2:]) < 4:
        raise ValueError(f"image must be (3, H, W) with H, W >= 4, got shape {tuple(image.shape)}")
    return image.double()


def _neighbour_phases(planes: Tensor) -> Tensor:
    """``(C, 2, 2)``: per plane of ``planes`` ``(C, H, W)``, the energy of its difference to the mean of its 4 edge
    neighbours at each phase of the 2×2 grid, over its mean."""
    padded = F.pad(planes[None], (1, 1, 1, 1), mode="reflect")[0]
    around = (padded[:, :-2, 1:-1] + padded[:, 2:, 1:-1] + padded[:, 1:-1, :-2] + padded[:, 1:-1, 2:]) / 4
    squared = (planes - around).pow(2)
    height, width = planes.shape[-2] // 2 * 2, planes.shape[-1] // 2 * 2
    phases = squared[:, :height, :width].reshape(len(planes), height // 2, 2, width // 2, 2).mean((1, 3))
    return phases / phases.mean((1, 2), keepdim=True).clamp_min(1e-20)


def colour_phase_share(phases: Tensor, pattern: str) -> float:
    """How much less of ``phases`` (a ``(3, 2, 2)`` of :func:`phase_error` or :func:`interpolation_phases`) red holds
    where ``pattern`` samples it than blue holds there, and blue where it samples blue than red there (the geometric
    mean of the two ratios): 0 for an exact mosaic of ``pattern`` in a :func:`phase_error`, 1 where red and blue share
    one phase pattern (no mosaic, or a grid common to all channels, as a resampler or JPEG leaves), the reciprocal for
    the layout with red and blue swapped. Green is not read: every layout samples it on one of the two diagonals."""
    masks = bayer_masks(2, 2, pattern).bool()
    red_site, blue_site = masks[0], masks[2]
    red, blue = phases[0].double().clamp_min(1e-12), phases[2].double().clamp_min(1e-12)
    return float(((red[red_site] / blue[red_site]) * (blue[blue_site] / red[blue_site])).sqrt())
