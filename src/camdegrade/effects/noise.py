"""Sensor stage: signal-dependent Poisson–Gaussian noise, and its estimator from aligned pairs."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from camdegrade._checks import check_non_negative
from camdegrade._random import standard_normal
from camdegrade.effects._common import batch_shape, resolve_params, vector
from camdegrade.effects._fitting import PairList, as_pairs
from camdegrade.effects.base import Effect, Encoding, Pairs, register_effect
from camdegrade.functional import poisson_gaussian_noise_image, srgb_to_linear
from camdegrade.functional.analysis import gradient_energy
from camdegrade.functional.noise import add_poisson_gaussian_noise_


@register_effect
class Noise(Effect):
    """Heteroscedastic sensor noise: variance ``a · I + b`` on the linear intensity ``I``, plus row banding.

    Args:
        a: shot-noise gain per channel (scalar or ``(3,)``). Neutral 0.
        b: read-noise variance per channel (scalar or ``(3,)``). Neutral 0.
        row_sigma: standard deviation of a per-row offset per channel (banding). Neutral 0.
        linear: apply the noise in linear light (default) rather than on sRGB values.
        gain_jitter: standard deviation of a per-sample log sensor gain (ISO variation between shots): the gain
            ``g`` scales ``a`` by ``g``, ``b`` by ``g²`` and ``row_sigma`` by ``g``. 0 disables it.

    ``make_params`` draws every standard normal the forward pass uses, so a seeded generator replays a capture
    byte for byte.

    References:
        A. Foi, M. Trimeche, V. Katkovnik, K. Egiazarian, "Practical Poissonian-Gaussian noise modeling and fitting
        for single-image raw-data", IEEE Transactions on Image Processing 17(10), 2008.
    """

    name = "noise"
    stage = "sensor"
    explains = ("noise",)
    a: Tensor
    b: Tensor
    row_sigma: Tensor

    def __init__(
        self,
        a: float | Tensor = 0.0,
        b: float | Tensor = 0.0,
        row_sigma: float | Tensor = 0.0,
        *,
        linear: bool = True,
        gain_jitter: float = 0.0,
    ) -> None:
        super().__init__()
        for key, value in (("a", a), ("b", b), ("row_sigma", row_sigma)):
            tensor = vector(value, 3, key)
            if bool((tensor < 0).any()):
                raise ValueError(f"{key} must be non-negative, got {key}={tensor.tolist()}")
            self.register_buffer(key, tensor)
        self.linear = bool(linear)
        self.gain_jitter = check_non_negative(gain_jitter, "gain_jitter")

    def config(self) -> dict[str, Any]:
        return {"linear": self.linear, "gain_jitter": self.gain_jitter}

    def without_randomness(self) -> None:
        """None: the stage only adds zero-mean noise, so the conditional mean leaves it out."""
        return None

    @classmethod
    def fit_options(cls, images: Sequence[Tensor]) -> dict[str, Any]:
        """Few or small pairs: intensity bins with at least 50 pixels count."""
        return {"min_count": 50}

    def make_params(
        self, shape: torch.Size | tuple[int, ...], generator: torch.Generator | None = None
    ) -> dict[str, Tensor]:
        n, channels, height, width = batch_shape(shape)
        params = {
            "normal": standard_normal((n, channels, height, width), generator),
            "row_normal": torch.randn(n, channels, height, 1, generator=generator),
        }
        if self.gain_jitter > 0:
            params["gain"] = torch.exp(torch.randn(n, generator=generator) * self.gain_jitter)
        return params

    def forward(self, image: Tensor, params: Mapping[str, Tensor] | None = None) -> Tensor:
        drawn, (a, b, rows) = self._levels(image, params)
        return poisson_gaussian_noise_image(
            image, a, b, drawn["normal"], row_sigma=rows, row_normal=drawn["row_normal"], linear=self.linear
        )

    def encodings(self) -> tuple[Encoding, Encoding]:
        return ("linear", "linear") if self.linear else ("srgb", "srgb")

    def forward_encoded(self, image: Tensor, params: Mapping[str, Tensor] | None = None) -> Tensor:
        drawn, levels = self._levels(image, params)
        a, b, rows = (value[..., None, None] for value in levels)  # (3, 1, 1), or (N, 3, 1, 1) with a gain
        row_normal = drawn["row_normal"] if bool((self.row_sigma > 0).any()) else None
        return add_poisson_gaussian_noise_(image, a, b, drawn["normal"], rows, row_normal)

    def _levels(
        self, image: Tensor, params: Mapping[str, Tensor] | None
    ) -> tuple[dict[str, Tensor], tuple[Tensor, Tensor, Tensor]]:
        """The drawn params on ``image``'s device and this capture's ``(a, b, row_sigma)`` after the ISO gain."""
        drawn = resolve_params(self, image, params)
        a, b, rows = (value.to(image.device) for value in (self.a, self.b, self.row_sigma))
        if "gain" in drawn:
            gain = drawn["gain"][:, None]
            a, b, rows = a * gain, b * gain**2, rows * gain
        return drawn, (a, b, rows)

    @classmethod
    def fit(
        cls,
        source: Pairs,
        target: Pairs,
        *,
        bins: int = 32,
        min_count: int = 200,
        flat_quantile: float = 0.5,
        rows: bool = True,
        linear: bool = True,
        max_pixels: int | None = 100_000,
    ) -> Noise:
        """Closed form: robust residual variance binned by intensity, then a weighted non-negative line fit.

        ``source`` is the clean image (for real pairs, the mean of many frames), ``target`` one noisy capture.
        See :func:`noise_level_function` for the binning. ``rows`` also estimates row banding from the
        variance of row means in excess of what the pixel noise explains. Bins where the capture clips are
        left out, so when noise is strong next to the darkest unclipped level, ``b`` rests on extrapolation.
        Recovery on synthetic pairs: ``a`` and ``b`` within 10 %, ``row_sigma`` within 25 %.
        """
        pairs = as_pairs(source, target)
        levels = noise_level_function(
            pairs, bins=bins, min_count=min_count, flat_quantile=flat_quantile, linear=linear, max_pixels=max_pixels
        )
        a, b = levels.fit_line()
        row_sigma = _row_sigma(pairs, flat_quantile, linear) if rows else torch.zeros(3)
        return cls(a, b, row_sigma, linear=linear)


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


def _flat_mask(source: Tensor, quantile: float) -> Tensor:
    """``(H, W)`` pixels whose local gradient is below the ``quantile`` of the image (1 keeps everything)."""
    energy = gradient_energy(source)
    if quantile >= 1:
        return torch.ones_like(energy, dtype=torch.bool)
    threshold = torch.quantile(energy.flatten()[:: max(1, energy.numel() // 100_000)], quantile)
    return energy <= threshold


def _residuals(pairs: PairList, flat_quantile: float, linear: bool) -> list[tuple[Tensor, Tensor, Tensor, Tensor]]:
    out = []
    for src, tgt in pairs:
        mask = _flat_mask(src, flat_quantile)
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
    """Measure the noise variance of ``target − source`` against the clean intensity, per channel.

    Pixels are binned by their sRGB source value (``bins`` equal bins), restricted to the flattest
    ``flat_quantile`` of each image (edges carry residual misalignment and demosaicking error, not noise).
    In each bin the variance is taken over the residuals within 5 robust
    (MAD) standard deviations of the median, which keeps outliers out without the 8-bit quantisation bias a pure
    MAD estimate has. Bins with fewer than ``min_count`` pixels, or where the capture clips at 0 or 1 in
    more than 0.5 % of pixels, are NaN. At most ``max_pixels`` evenly strided pixels per image are used
    (``None``: all), which bounds the cost on large real pairs.
    """
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


def _row_sigma(pairs: PairList, flat_quantile: float, linear: bool) -> Tensor:
    """Per-channel banding std: the variance of row means beyond what the noise without banding explains.

    That null is the larger of two predictions: independent pixels (pixel variance / pixels per row), and the
    column means (banding moves rows, not columns; their variance, scaled by the pixels per column over the
    pixels per row, is what row means would show without it). The second holds for spatially correlated noise
    and for 8×8 codec blocking, which raise row and column means alike and would otherwise read as banding.
    """
    estimates = torch.zeros(3)
    weights = 0
    for _, _, diff, mask in _residuals(pairs, flat_quantile, linear):
        row_counts, column_counts = mask.sum(1).double(), mask.sum(0).double()
        rows = row_counts >= max(8, mask.shape[1] // 4)
        columns = column_counts >= max(8, mask.shape[0] // 4)
        if int(rows.sum()) < 8 or int(columns.sum()) < 8:
            continue
        length_ratio = float(column_counts[columns].median() / row_counts[rows].median())
        for channel in range(3):
            r = diff[channel].double() * mask
            means = r.sum(1)[rows] / row_counts[rows]
            spread = (r.pow(2).sum(1)[rows] / row_counts[rows] - means.pow(2)) / (row_counts[rows] - 1)
            column_means = r.sum(0)[columns] / column_counts[columns]
            null = max(float(spread.median()), _robust_variance(column_means) * length_ratio)
            estimates[channel] += max(_robust_variance(means) - null, 0.0) * int(rows.sum())
        weights += int(rows.sum())
    return (estimates / max(weights, 1)).sqrt()


def _robust_variance(values: Tensor) -> float:
    """Variance from the median absolute deviation (Gaussian-consistent), unmoved by a few outlying rows."""
    return float((1.4826 * (values - values.median()).abs().median()) ** 2)
