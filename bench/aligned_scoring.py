"""Alignment-tolerant PSNR for the restoration-transfer bench (``bench_restoration_transfer.py``).

City100's captures are registered to their clean images only to within about a pixel, and not by one shift over the
frame. A restorer that sharpens a capture 0.7 px off its clean image loses PSNR for the misregistration, not for the
restoration. So the image is cut into tiles of ``tile``² (a ``margin`` left around the frame) and each tile of the
restored image is moved, by the sub-pixel shift that gives it the least squared error against the clean tile, before
it is scored: an integer search over ``±radius`` pixels, then a 3×3 pattern search at steps of 1/2, 1/4, 1/8 and
1/16 pixel around the best shift so far, and last the vertex of a parabola through the 3×3 errors at 1/16 px
around it, per axis (kept where it scores better). A tile is
moved by separable Lanczos-3 interpolation, which reads at most ``radius + 3`` pixels beyond it (inside the margin,
so no tile reads past the frame).

References:
    C. E. Duchon, "Lanczos Filtering in One and Two Dimensions", Journal of Applied Meteorology 18(8), 1979.
"""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

#: Lanczos lobes: the interpolation kernel is zero beyond this many pixels.
LOBES = 3
#: The steps (pixels) of the pattern search after the integer search.
REFINE_STEPS = (0.5, 0.25, 0.125, 0.0625)
#: The 3×3 pattern (rows, columns), its centre at index 4.
NEIGHBOURS = torch.tensor([(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1)], dtype=torch.float32)


@dataclass(frozen=True)
class TileGrid:
    """Tiles of ``tile``² scored, at least ``margin`` pixels from the frame's edge; shifts up to ``radius`` pixels."""

    tile: int = 96
    margin: int = 8
    radius: int = 3

    def __post_init__(self) -> None:
        if self.margin < self.radius + 1 + LOBES:
            raise ValueError(f"margin must be at least radius + {1 + LOBES}, got margin={self.margin}")

    def origins(self, height: int, width: int) -> list[tuple[int, int]]:
        """Top-left corners of the tiles, the grid centred in the frame inside the margin."""
        rows, columns = ((size - 2 * self.margin) // self.tile for size in (height, width))
        if rows < 1 or columns < 1:
            raise ValueError(f"image must be at least {self.tile + 2 * self.margin} px a side, got {height}x{width}")
        top = (height - rows * self.tile) // 2
        left = (width - columns * self.tile) // 2
        return [(top + r * self.tile, left + c * self.tile) for r in range(rows) for c in range(columns)]


@dataclass(frozen=True)
class Aligned:
    """The scored tiles of one image: ``tiles`` ``(T, 3, tile, tile)`` of the restored image moved by ``shifts``
    ``(T, 2)`` (rows, columns: the tile shows the image at ``position + shift``), the clean tiles ``references`` and
    the per-tile mean squared error ``errors`` ``(T,)``."""

    tiles: Tensor
    references: Tensor
    shifts: Tensor
    errors: Tensor

    @property
    def psnr_db(self) -> float:
        error = float(self.errors.mean())
        return -10 * math.log10(error) if error > 0 else math.inf


def lanczos_taps(shifts: Tensor, reach: int) -> Tensor:
    """``(..., 2·reach + 1)`` weights that read the samples at offsets ``−reach … reach`` to interpolate the signal
    at ``+shift``; normalised to sum to 1 (a flat image stays flat)."""
    offsets = torch.arange(-reach, reach + 1, dtype=shifts.dtype)
    distance = shifts[..., None] - offsets
    weights = torch.sinc(distance) * torch.sinc(distance / LOBES) * (distance.abs() < LOBES)
    return weights / weights.sum(-1, keepdim=True)


def shifted(windows: Tensor, shifts: Tensor, reach: int) -> Tensor:
    """``(T, K, 3, S, S)``: each window ``(T, 3, S + 2·reach, S + 2·reach)`` read at ``+shift`` for each of its
    ``K`` shifts ``(T, K, 2)`` (|shift| ≤ reach − 3), its centre ``S``² kept."""
    count, candidates = shifts.shape[:2]
    side = windows.shape[-1] - 2 * reach
    taps = lanczos_taps(shifts.double(), reach).to(windows.dtype)  # (T, K, 2, 2·reach + 1)
    planes = windows[:, None].expand(count, candidates, *windows.shape[1:]).reshape(1, -1, *windows.shape[-2:])
    across = taps[:, :, 1, None].expand(-1, -1, 3, -1)
    down = taps[:, :, 0, None].expand(-1, -1, 3, -1)
    planes = F.conv2d(planes, across.reshape(-1, 1, 1, 2 * reach + 1), groups=planes.shape[1])
    planes = F.conv2d(planes, down.reshape(-1, 1, 2 * reach + 1, 1), groups=planes.shape[1])
    return planes.reshape(count, candidates, 3, side, side)


def _errors(windows: Tensor, references: Tensor, shifts: Tensor, reach: int) -> Tensor:
    return (shifted(windows, shifts, reach) - references[:, None]).pow(2).mean((-3, -2, -1))


def _integer_search(windows: Tensor, references: Tensor, radius: int, reach: int) -> Tensor:
    """``(T, 2)``: each tile's best whole-pixel shift within ``±radius``."""
    side = references.shape[-1]
    best, best_error = torch.zeros(len(windows), 2), torch.full((len(windows),), math.inf)
    for dy in range(-radius, radius + 1):
        for dx in range(-radius, radius + 1):
            crop = windows[..., reach + dy : reach + dy + side, reach + dx : reach + dx + side]
            error = (crop - references).pow(2).mean((-3, -2, -1))
            better = error < best_error
            best[better], best_error = torch.tensor([float(dy), float(dx)]), torch.where(better, error, best_error)
    return best


def align_tiles(image: Tensor, reference: Tensor, grid: TileGrid = TileGrid()) -> Aligned:
    """Every tile of ``grid`` of the float ``(3, H, W)`` ``image`` moved to best match ``reference``'s."""
    if image.shape != reference.shape or image.dim() != 3 or image.shape[0] != 3:
        raise ValueError(
            f"image and reference must be (3, H, W) of one shape, got {tuple(image.shape)} and {tuple(reference.shape)}"
        )
    reach, side = grid.margin, grid.tile
    origins = grid.origins(*image.shape[-2:])
    image, reference = image.float(), reference.float()
    windows = torch.stack([image[:, t - reach : t + side + reach, s - reach : s + side + reach] for t, s in origins])
    references = torch.stack([reference[:, t : t + side, s : s + side] for t, s in origins])
    shifts = _integer_search(windows, references, grid.radius, reach)
    with torch.no_grad():
        for step in REFINE_STEPS:
            errors = _errors(windows, references, shifts[:, None] + step * NEIGHBOURS, reach)
            shifts = shifts + step * NEIGHBOURS[errors.argmin(1)]
        step = REFINE_STEPS[-1]
        errors = _errors(windows, references, shifts[:, None] + step * NEIGHBOURS, reach)
        polished = shifts + step * _parabola_vertex(errors.view(-1, 3, 3))
        tiles = shifted(windows, torch.stack([shifts, polished], 1), reach)
        tile_errors = (tiles - references[:, None]).pow(2).mean((-3, -2, -1))
        better = tile_errors[:, 1] < tile_errors[:, 0]
        pick = better.long()
        index = torch.arange(len(tiles))
    return Aligned(
        tiles[index, pick], references, torch.where(better[:, None], polished, shifts), tile_errors[index, pick]
    )


def _parabola_vertex(errors: Tensor) -> Tensor:
    """``(T, 2)``: per axis, the vertex (in steps, within ±1/2) of the parabola through the centre row and column
    of each ``(3, 3)`` error patch; 0 where the patch's centre is not its least or the parabola opens down."""
    offsets = []
    for line in (errors[:, :, 1], errors[:, 1, :]):  # rows (down), then columns (across)
        curvature = line[:, 0] - 2 * line[:, 1] + line[:, 2]
        vertex = 0.5 * (line[:, 0] - line[:, 2]) / curvature.clamp_min(1e-30)
        offsets.append(torch.where(curvature > 0, vertex.clamp(-0.5, 0.5), torch.zeros_like(vertex)))
    centre_least = errors.flatten(1).argmin(1) == 4
    return torch.where(centre_least[:, None], torch.stack(offsets, 1), torch.zeros(len(errors), 2))


def aligned_psnr(image: Tensor, reference: Tensor, grid: TileGrid = TileGrid()) -> float:
    """PSNR (dB) of ``image`` against ``reference`` over the tiles of ``grid``, each tile moved by its own
    sub-pixel shift first (:func:`align_tiles`)."""
    return align_tiles(image, reference, grid).psnr_db


def unaligned_psnr(image: Tensor, reference: Tensor, grid: TileGrid = TileGrid()) -> float:
    """PSNR (dB) of ``image`` against ``reference`` over the same tiles as :func:`aligned_psnr`, none moved."""
    origins = grid.origins(*image.shape[-2:])
    side = grid.tile
    error = statistics.fmean(
        float((image[:, t : t + side, s : s + side] - reference[:, t : t + side, s : s + side]).pow(2).mean())
        for t, s in origins
    )
    return -10 * math.log10(error) if error > 0 else math.inf
