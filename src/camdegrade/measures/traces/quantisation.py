"""The fingerprint JPEG leaves in a decoded image: its 8×8 blocks' DCT coefficients on the quantisation lattice.

A JPEG stores each 8×8 block's luma DCT coefficients as integer multiples of a quantisation step per frequency; the
decoded image (rounded to 8 bits, converted to RGB and back) still holds them within about 0.35 of those
multiples, in blocks aligned to the image's origin. A resize, a blur or any other resampling leaves periodic
structure and block-edge energy but no such lattice, and blocks shifted off the origin (the control) show none for
a JPEG either. So a lossless file that once was a JPEG is told from one that never was by the lattice alone, and the
step found at each frequency is the table's (``tests/test_jpeg_lattice.py``: PIL's resizes by bilinear, bicubic,
Lanczos, box and nearest filters at 0.3–2× read 0 frequencies on the lattice, JPEGs of quality 30–95 saved as PNG
6–14, their steps those of the tables).

References:
    Z. Fan, R. L. de Queiroz, "Identification of bitmap compression history: JPEG detection and quantizer
    estimation", IEEE Trans. Image Processing 12(2), 2003 (decoded JPEG coefficients cluster at multiples of the
    quantiser step).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from camdegrade._support.pixels import as_unit

__all__ = ["FREQUENCIES", "MIN_FREQUENCIES", "LatticeReading", "block_coefficients", "lattice_scores", "read_lattice"]

#: The AC frequencies ``(u, v)`` (vertical, horizontal) read: the low ones (``u + v`` from 1 to 4), where a photo's
#: coefficients are mostly off zero. Their steps at quality 95 are 1 or 2, at 30 from 17 to 40.
FREQUENCIES: tuple[tuple[int, int], ...] = tuple(
    (u, v) for total in range(1, 5) for u in range(total + 1) for v in (total - u,)
)
#: Candidate steps (a step of 1 is no lattice: 8-bit rounding alone puts every coefficient that near one).
STEPS = torch.arange(2, 129, dtype=torch.float64)
#: Width (in coefficient units) of the kernel that scores a coefficient's distance to the lattice: decoding and
#: 8-bit rounding move a JPEG's coefficients off it by a standard deviation of about 0.35.
KERNEL = 0.5
#: A step is read from at least this many coefficients off zero (at least half a step from it): 20 read JPEGs of
#: quality 20–95 in crops of 96² (144 blocks) at their exact steps, where 50 left a third of the crops unread.
MIN_COEFFICIENTS = 20
#: At most this many blocks of an image are read (evenly spaced).
MAX_BLOCKS = 1024
#: A frequency is on the lattice at a step when its score there (0: chance, 1: every coefficient on a multiple)
#: reaches :data:`ON_LATTICE` on the origin's grid and stays below :data:`OFF_GRID` on the grid shifted by half a
#: block: quality 95 scores about 0.55 at its steps of 2, resized photos at most 0.1.
ON_LATTICE = 0.4
OFF_GRID = 0.2
#: ... and within this much of the frequency's best score: the true step and its divisors score alike, a multiple of
#: it (which a few coefficients at even multiples can lift above :data:`ON_LATTICE`) well below.
NEAR_BEST = 0.1
#: An image was a JPEG when at least this many :data:`FREQUENCIES` are on the lattice (quality 95: 6; 98: none).
MIN_FREQUENCIES = 3


@dataclass(frozen=True)
class LatticeReading:
    """One image's reading: the quantisation step found at each of :data:`FREQUENCIES` (``None``: too few
    coefficients off zero to tell; 1: no lattice), and whether enough of them are on it (``compressed``)."""

    steps: tuple[int | None, ...]

    @property
    def on_lattice(self) -> int:
        return sum(1 for step in self.steps if step is not None and step >= 2)

    @property
    def compressed(self) -> bool:
        return self.on_lattice >= MIN_FREQUENCIES

    @property
    def determined(self) -> bool:
        """Whether the image says either way: on the lattice, or at least :data:`MIN_FREQUENCIES` frequencies read
        and off it (a smooth image's coefficients are too few to tell)."""
        return self.compressed or sum(1 for step in self.steps if step == 1) >= MIN_FREQUENCIES


def _dct_matrix() -> Tensor:
    """The orthonormal 8-point DCT-II (JPEG's transform, rows are frequencies)."""
    n = torch.arange(8, dtype=torch.float64)
    matrix = torch.cos((2 * n[None, :] + 1) * n[:, None] * math.pi / 16) * 0.5
    matrix[0] = math.sqrt(1 / 8)
    return matrix


def block_coefficients(image: Tensor, offset: int = 0) -> Tensor:
    """``(len(FREQUENCIES), B)`` luma DCT coefficients (JPEG's BT.601 luma in 0–255, level-shifted) of the 8×8 blocks
    of ``image`` (``(3, H, W)``, uint8 or float in [0, 1]) whose grid starts ``offset`` pixels from the origin
    down and right, leaving out blocks with a pixel at 0 or 255 in any channel or in luma; at most
    :data:`MAX_BLOCKS`, evenly spaced."""
    rgb = (as_unit(image).double() * 255)[:, offset:, offset:]
    rows, cols = rgb.shape[1] // 8, rgb.shape[2] // 8
    rgb = rgb[:, : rows * 8, : cols * 8]
    luma = 0.299 * rgb[0] + 0.587 * rgb[1] + 0.114 * rgb[2] - 128
    blocks = luma.reshape(rows, 8, cols, 8).transpose(1, 2).reshape(-1, 8, 8)
    # A decoder clips its luma and then RGB to 0–255: a block with a clipped value no longer holds the lattice.
    rgb_clipped = ((rgb <= 0.5) | (rgb >= 254.5)).any(0)
    luma_clipped = (luma <= -127.0) | (luma >= 126.0)
    clipped = (rgb_clipped | luma_clipped).reshape(rows, 8, cols, 8).transpose(1, 2).reshape(-1, 64)
    blocks = blocks[~clipped.any(1)]
    if blocks.shape[0] > MAX_BLOCKS:
        blocks = blocks[torch.linspace(0, blocks.shape[0] - 1, MAX_BLOCKS).round().long()]
    dct = _dct_matrix()
    coefficients = dct @ blocks @ dct.T
    return torch.stack([coefficients[:, u, v] for u, v in FREQUENCIES])


def lattice_scores(coefficients: Tensor) -> Tensor:
    """``(F, len(STEPS))``: per frequency and candidate step ``q``, the mean closeness of the coefficients at least
    ``q/2`` from zero to their nearest multiple of ``q`` (a Gaussian kernel of :data:`KERNEL`), rescaled so that
    coefficients spread evenly score 0 and all on the lattice 1; NaN where fewer than :data:`MIN_COEFFICIENTS`."""
    steps = STEPS[:, None, None]
    values = coefficients[None]
    away = values.abs() >= steps / 2
    distance = values - steps * torch.round(values / steps)
    closeness = torch.exp(-distance.pow(2) / (2 * KERNEL**2))
    count = away.sum(-1)
    mean = (closeness * away).sum(-1) / count.clamp_min(1)
    half = STEPS / 2
    chance = KERNEL * math.sqrt(2 * math.pi) * torch.erf(half / (KERNEL * math.sqrt(2))) / STEPS  # evenly spread
    score = (mean - chance[:, None]) / (1 - chance[:, None])
    return torch.where(count >= MIN_COEFFICIENTS, score, torch.nan).T


def read_lattice(image: Tensor) -> LatticeReading:
    """The quantisation step of each of :data:`FREQUENCIES` in ``image``: the largest candidate on the lattice on the
    origin's 8×8 grid (:data:`ON_LATTICE`, :data:`NEAR_BEST`) and not on the grid shifted by 4 pixels
    (:data:`OFF_GRID`)."""
    aligned = lattice_scores(block_coefficients(image))
    shifted = lattice_scores(block_coefficients(image, offset=4))
    steps: list[int | None] = []
    for here, control in zip(aligned, shifted, strict=True):
        best = float(here.nan_to_num(-1.0).max())
        near_best = here >= max(ON_LATTICE, best - NEAR_BEST)
        found = torch.nonzero(near_best & ~(control >= OFF_GRID)).flatten()
        if found.numel():
            steps.append(int(STEPS[found[-1]]))
        else:
            steps.append(1 if bool(torch.isfinite(here[0])) else None)
    return LatticeReading(tuple(steps))
