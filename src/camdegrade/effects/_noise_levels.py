"""The old noise-level measurement (deprecated): residual variance binned by intensity on a share of each image's
flattest pixels. Superseded by :class:`camdegrade.functional.noise_stats.NoiseSums`, which measures only where the
clean image is flat in absolute terms (a detailed frame's flattest half still holds texture)."""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import torch
from torch import Tensor

from camdegrade.effects._fitting import PairList, as_pairs
from camdegrade.effects.base import Pairs
from camdegrade.functional import srgb_to_linear
from camdegrade.functional.analysis import relative_flat_mask


@dataclass(frozen=True)
class NoiseLevels:
    """A measured noise-level function: per channel and intensity bin, the robust residual variance.

    Attributes:
        intensity: ``(3, B)`` mean clean intensity of each bin (linear light unless fitted with linear=False).
        variance: ``(3, B)`` robust variance of ``target − source`` in the bin (NaN where too few pixels).
        count: ``(3, B)`` number of pixels used.
    """

    intensity: Tensor
    variance: Tensor
    count: Tensor

    def fit_line(self) -> tuple[Tensor, Tensor]:
        """Weighted non-negative least squares ``variance ≈ a · intensity + b`` per channel → ``(a, b)``."""
        a, b = torch.zeros(3), torch.zeros(3)
        for channel in range(3):
            valid = torch.isfinite(self.variance[channel])
            if int(valid.sum()) < 2:
                raise ValueError("too few populated intensity bins to fit a noise level; use larger pairs")
            x = self.intensity[channel, valid].double()
            v = self.variance[channel, valid].double()
            n = self.count[channel, valid].double()
            fitted = v
            for _ in range(3):  # reweight with the fitted variance: Var(sample variance) ∝ variance² / n
                weights = n / fitted.clamp_min(1e-12) ** 2
                slope, offset = _nonnegative_line(x, v, weights)
                fitted = slope * x + offset
            a[channel], b[channel] = float(slope), float(offset)
        return a, b


def _nonnegative_line(x: Tensor, y: Tensor, w: Tensor) -> tuple[Tensor, Tensor]:
    sw, sx, sy = w.sum(), (w * x).sum(), (w * y).sum()
    sxx, sxy = (w * x * x).sum(), (w * x * y).sum()
    determinant = sw * sxx - sx * sx
    slope = (sw * sxy - sx * sy) / determinant if determinant > 0 else torch.zeros((), dtype=x.dtype)
    offset = (sy - slope * sx) / sw
    if slope < 0:
        return torch.zeros((), dtype=x.dtype), (sy / sw).clamp_min(0.0)
    if offset < 0:
        return (sxy / sxx).clamp_min(0.0), torch.zeros((), dtype=x.dtype)
    return slope, offset


def _residuals(pairs: PairList, flat_quantile: float, linear: bool) -> list[tuple[Tensor, Tensor, Tensor, Tensor]]:
    out = []
    for src, tgt in pairs:
        mask = relative_flat_mask(src, flat_quantile)
        clean = srgb_to_linear(src) if linear else src
        noisy = srgb_to_linear(tgt) if linear else tgt
        out.append((src, clean, noisy - clean, mask))
    return out


def noise_level_function(
    pairs: PairList | tuple[Pairs, Pairs],
    *,
    bins: int = 32,
    min_count: int = 200,
    flat_quantile: float = 0.5,
    linear: bool = True,
    max_pixels: int | None = 100_000,
) -> NoiseLevels:
    """Deprecated: measure the noise variance of ``target − source`` against the clean intensity, per channel.

    Use :class:`camdegrade.functional.noise_stats.NoiseSums` (absolute flatness, pixel counts, correlation and
    banding) instead.

    Pixels are binned by their sRGB source value (``bins`` equal bins), restricted to the flattest
    ``flat_quantile`` of each image (edges carry residual misalignment and demosaicking error, not noise).
    In each bin the variance is taken over the residuals within 5 robust
    (MAD) standard deviations of the median, which keeps outliers out without the 8-bit quantisation bias a pure
    MAD estimate has. Bins with fewer than ``min_count`` pixels, or where the capture clips at 0 or 1 in
    more than 0.5 % of pixels, are NaN. At most ``max_pixels`` evenly strided pixels per image are used
    (``None``: all), which bounds the cost on large real pairs.
    """
    warnings.warn(
        "noise_level_function is deprecated and will be removed: measure noise with "
        "camdegrade.functional.noise_stats.NoiseSums (flat pixels in absolute terms)",
        DeprecationWarning,
        stacklevel=2,
    )
    pair_list = as_pairs(*pairs) if isinstance(pairs, tuple) else pairs
    keys, values, residuals = [], [], []
    for src, clean, diff, mask in _residuals(pair_list, flat_quantile, linear):
        stride = max(1, math.ceil(int(mask.sum()) / max_pixels)) if max_pixels else 1
        channel_offset = torch.arange(3)[:, None] * bins  # one key space for the three channels
        keys.append((src[:, mask][:, ::stride] * bins).long().clamp(0, bins - 1) + channel_offset)
        values.append(clean[:, mask][:, ::stride])
        residuals.append(diff[:, mask][:, ::stride])
    key = torch.cat(keys, 1).flatten()
    value = torch.cat(values, 1).flatten().double()
    residual = torch.cat(residuals, 1).flatten().double()
    size = 3 * bins
    count = torch.bincount(key, minlength=size).double()
    noisy = value + residual
    clipped = torch.bincount(key, weights=((noisy <= 1e-6) | (noisy >= 1 - 1e-6)).double(), minlength=size)
    mean_intensity = torch.bincount(key, weights=value, minlength=size) / count.clamp_min(1)
    variance = _binned_robust_variance(key, residual, count)
    valid = (count >= min_count) & (clipped <= 0.005 * count)
    nan = torch.tensor(float("nan"), dtype=torch.float64)
    return NoiseLevels(
        intensity=torch.where(valid, mean_intensity, nan).float().reshape(3, bins),
        variance=torch.where(valid, variance, nan).float().reshape(3, bins),
        count=torch.where(valid, count, 0.0).float().reshape(3, bins),
    )


def _binned_median(key: Tensor, values: Tensor, count: Tensor) -> Tensor:
    """Per-bin (upper) median of ``values`` grouped by integer ``key``, vectorised by a two-pass stable sort."""
    order = torch.sort(values, stable=True).indices
    order = order[torch.sort(key[order], stable=True).indices]  # by key, then by value within a key
    starts = torch.cumsum(count, 0) - count
    middle = (starts + torch.div(count, 2, rounding_mode="floor")).long().clamp(0, max(0, values.numel() - 1))
    return values[order][middle] if values.numel() else torch.zeros_like(count)


def _binned_robust_variance(key: Tensor, residual: Tensor, count: Tensor) -> Tensor:
    """Per-bin variance of the residuals within 5 robust (MAD) standard deviations of the bin median."""
    size = count.numel()
    median = _binned_median(key, residual, count)
    deviation = (residual - median[key]).abs()
    mean = torch.bincount(key, weights=residual, minlength=size) / count.clamp_min(1)
    second = torch.bincount(key, weights=residual**2, minlength=size) / count.clamp_min(1)
    fallback = (second - mean**2).clamp_min(0).sqrt()  # quantised data with MAD 0: use the plain std
    mad = 1.4826 * _binned_median(key, deviation, count)
    spread = torch.where(mad > 0, mad, fallback)
    kept = (deviation <= 5 * spread[key]).double()
    n = torch.bincount(key, weights=kept, minlength=size)
    s1 = torch.bincount(key, weights=residual * kept, minlength=size)
    s2 = torch.bincount(key, weights=residual**2 * kept, minlength=size)
    return ((s2 - s1**2 / n.clamp_min(1)) / (n - 1).clamp_min(1)).clamp_min(0)
