"""Quantization kernel: every value snapped to the nearest level of a per-channel codebook.

A uniform codebook of ``2**bits`` levels is an ADC or a buffer of ``bits`` bits. A buffer quantized *before* a tone
curve has its levels where the curve puts the uniform ones: the camera's output holds only those values (a
posterised gradient, a histogram with combs of skipped codes), and the codebook is that curve sampled at the
uniform levels. Snapping to the nearest level of the codebook (thresholds halfway between adjacent levels) is exact
for a uniform codebook and, for a curved one, within a quarter of a level's spacing times the curve's change of
slope over one level.

References:
    R. M. Gray, D. L. Neuhoff, "Quantization", IEEE Trans. Information Theory 44(6), 1998 (scalar quantizers,
    codebooks and their decision thresholds).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from camdegrade.functional._utils import apply_float, check_image
from camdegrade.functional.sensor.resolution import sensor_size

__all__ = [
    "code_histogram",
    "histogram_comb",
    "histogram_peaks",
    "local_mean",
    "quantize_image",
    "skipped_runs",
    "uniform_codebook",
]


def uniform_codebook(levels: int, dtype: torch.dtype = torch.float32) -> Tensor:
    """``(3, levels)``: ``levels`` evenly spaced values from 0 to 1 for each channel (``levels`` at least 2)."""
    if not isinstance(levels, int) or isinstance(levels, bool) or levels < 2:
        raise ValueError(f"levels must be an integer of at least 2, got levels={levels!r}")
    return torch.linspace(0.0, 1.0, levels, dtype=dtype).expand(3, levels).clone()


def quantize_image(image: Tensor, codebook: Tensor, scale: float = 1.0) -> Tensor:
    """Each value of channel ``c`` replaced by the nearest value of ``codebook[c]``; with ``scale`` below 1, on a
    grid of ``scale`` of the image's resolution (a buffer before an upscale): the image's error to its quantized
    self at that resolution, upsampled, is added to it (clipped to [0, 1]).

    On a grid, ``x + up(Q(down x) − down x)``: a flat region comes out as its quantized value, as the camera's does
    (``up(Q(d))`` of its buffer ``d``), and the steps between levels come out as smooth as the upscale makes them,
    while the image's content (already upscaled by a ``resolution`` stage before it) is kept. ``down`` and ``up``
    are those of :func:`~camdegrade.functional.sensor.resolution.resolution_image` (bilinear antialiased, bicubic).

    Args:
        image: ``[..., 3, H, W]`` uint8 or float in [0, 1].
        codebook: ``(3, L)`` levels per channel, non-decreasing along ``L`` (``L`` at least 1).
        scale: the grid's resolution relative to the image's, in (0, 1] (1: every pixel).

    Examples:
        >>> image = torch.tensor([0.1, 0.3, 0.8]).reshape(1, 3, 1, 1).expand(1, 3, 2, 2)
        >>> quantize_image(image, torch.tensor([[0.0, 0.5, 1.0]] * 3))[0, :, 0, 0].tolist()
        [0.0, 0.5, 1.0]
    """
    check_image(image)
    if not isinstance(codebook, Tensor) or codebook.ndim != 2 or codebook.shape[0] != 3 or codebook.shape[1] < 1:
        shape = tuple(codebook.shape) if isinstance(codebook, Tensor) else type(codebook).__name__
        raise ValueError(f"codebook must have shape (3, L) with L >= 1, got {shape}")
    if bool((codebook[:, 1:] < codebook[:, :-1]).any()):
        raise ValueError("codebook must be non-decreasing along each channel's levels")
    if not 0.0 < float(scale) <= 1.0:
        raise ValueError(f"scale must be in (0, 1], got scale={scale!r}")
    height, width = image.shape[-2:]
    low = sensor_size(height, width, float(scale))
    if low == (height, width):
        return apply_float(image, lambda x: _snapped(x, codebook))

    def on_grid(x: Tensor) -> Tensor:
        flat = x.reshape(-1, *x.shape[-3:])
        sampled = F.interpolate(flat, size=low, mode="bilinear", antialias=True, align_corners=False)
        error = F.interpolate(_snapped(sampled, codebook) - sampled, size=(height, width), mode="bicubic")
        return (flat + error).clamp(0.0, 1.0).reshape(x.shape)

    return apply_float(image, on_grid)


def _snapped(x: Tensor, codebook: Tensor) -> Tensor:
    """Float values ``[..., 3, H, W]`` replaced by their nearest levels (thresholds halfway between levels)."""
    levels = codebook.to(device=x.device, dtype=x.dtype)
    thresholds = (levels[:, 1:] + levels[:, :-1]) / 2
    channels = x.movedim(-3, 0).reshape(3, -1).contiguous()
    index = torch.searchsorted(thresholds.contiguous(), channels)
    return torch.gather(levels, 1, index).reshape(x.movedim(-3, 0).shape).movedim(0, -3)


#: Codes either side of a code that its local mean covers (a window of 9 codes: a comb of a 5-bit buffer has one
#: level in it, a smooth histogram nine alike).
WINDOW = 4
#: A code's local mean must hold at least this many pixels for the code to be measured (Poisson scatter of the
#: histogram's counts, 1/sqrt(30) = 18 %, stays below the comb's contrast).
MIN_COUNT = 30.0


def code_histogram(image: Tensor) -> Tensor:
    """``(3, 256)`` float64: per channel, how many pixels of ``image`` (``(3, H, W)`` uint8 or float in [0, 1])
    hold each 8-bit code."""
    check_image(image)
    codes = image.long() if image.dtype == torch.uint8 else (image.double().clamp(0, 1) * 255).round().long()
    channels = codes.movedim(-3, 0).reshape(3, -1).cpu()
    keys = (channels + torch.arange(3)[:, None] * 256).flatten()
    return torch.bincount(keys, minlength=768).double().reshape(3, 256)


def local_mean(histogram: Tensor) -> Tensor:
    """Each code's count averaged over the :data:`WINDOW` codes either side (fewer at the ends)."""
    rows = histogram.double().reshape(-1, 1, histogram.shape[-1])
    mean = torch.nn.functional.avg_pool1d(rows, 2 * WINDOW + 1, 1, WINDOW, count_include_pad=False)
    return mean.reshape(histogram.shape)


def histogram_comb(histogram: Tensor) -> tuple[Tensor, Tensor]:
    """``(sum |h − local mean|, sum local mean)`` per channel over the measured codes (1–254, local mean of at least
    :data:`MIN_COUNT`): their ratio is 0 for a histogram smooth at the scale of a few codes (up to its Poisson
    scatter, about ``0.8 / sqrt(count per code)``), 0.2 for an 8-bit buffer through a contrast table (single codes
    skipped) and 1.7 for a 5-bit buffer (one code in eight occupied)."""
    histogram = histogram.double()
    mean = local_mean(histogram)
    measured = mean >= MIN_COUNT
    measured[..., 0] = measured[..., -1] = False
    return ((histogram - mean).abs() * measured).sum(-1), (mean * measured).sum(-1)


def skipped_runs(histogram: Tensor) -> Tensor:
    """The lengths of the runs of empty codes inside the measured range of a histogram of 8-bit codes (``(256,)``;
    local mean at least :data:`MIN_COUNT`): runs of one for a tone table on 8-bit values (it skips single codes
    where it is steeper than 1), of several for a coarse buffer, none for a histogram the noise or an upscale
    filled."""
    measured = local_mean(histogram) >= MIN_COUNT
    empty = ((histogram == 0) & measured).int()
    edges = torch.diff(torch.cat([torch.zeros(1, dtype=torch.int), empty, torch.zeros(1, dtype=torch.int)]))
    starts, ends = torch.nonzero(edges == 1).flatten(), torch.nonzero(edges == -1).flatten()
    return ends - starts


def histogram_peaks(histogram: Tensor, radius: int = 2) -> Tensor:
    """The levels a histogram of 8-bit codes (``(256,)``) is combed to, in [0, 1], ascending: the codes holding the
    most pixels within ``radius`` codes and at least half their local mean (and 10 pixels); of two closer than half
    the median spacing, the fuller; a gap over 1.5 times the spacing around it (a level too few pixels fell on)
    filled with evenly spaced levels; continued beyond the lowest and highest at their end spacings to 0 and 1."""
    histogram = histogram.double()
    window = torch.nn.functional.max_pool1d(histogram[None, None], 2 * radius + 1, 1, radius)[0, 0]
    peak = (histogram >= window) & (histogram >= 0.5 * local_mean(histogram)) & (histogram >= 10)
    codes = torch.nonzero(peak).flatten().tolist()
    if len(codes) < 2:
        return torch.tensor(codes, dtype=torch.float64) / 255.0
    spacing = float(torch.tensor(codes).diff().double().median())
    kept = [codes[0]]
    for code in codes[1:]:
        if code - kept[-1] >= spacing / 2:
            kept.append(code)
        elif histogram[code] > histogram[kept[-1]]:
            kept[-1] = code
    return _continued(_gaps_filled(torch.tensor(kept, dtype=torch.float64)) / 255.0)


def _gaps_filled(levels: Tensor, neighbours: int = 3) -> Tensor:
    """``levels`` with every gap over 1.5 times the median of the ``neighbours`` gaps either side of it split into
    that many even steps (a tone curve's spacing changes slowly from level to level)."""
    gaps = levels.diff()
    filled = [levels[:1]]
    for index, gap in enumerate(gaps.tolist()):
        around = torch.cat([gaps[max(0, index - neighbours) : index], gaps[index + 1 : index + 1 + neighbours]])
        local = float(around.median()) if around.numel() else gap
        steps = max(1, round(gap / local)) if gap > 1.5 * local else 1
        filled.append(levels[index] + gap * torch.arange(1, steps + 1, dtype=levels.dtype) / steps)
    return torch.cat(filled)


def _continued(levels: Tensor) -> Tensor:
    """``levels`` (at least two, ascending) continued below and above at their end spacings until 0 and 1."""
    if len(levels) < 2:
        return levels
    low_step, high_step = float(levels[1] - levels[0]), float(levels[-1] - levels[-2])
    below, above = [], []
    value = float(levels[0]) - low_step
    while low_step > 0 and value > -low_step / 2:
        below.insert(0, max(value, 0.0))
        value -= low_step
    value = float(levels[-1]) + high_step
    while high_step > 0 and value < 1 + high_step / 2:
        above.append(min(value, 1.0))
        value += high_step
    return torch.cat([torch.tensor(below, dtype=torch.float64), levels, torch.tensor(above, dtype=torch.float64)])
