"""Noise structure measured where the clean image is flat: level by intensity, spatial and chroma correlation,
row and column banding.

Every statistic rests on the pixels of :func:`~camdegrade.functional.analysis.images.flat_mask` (the clean image flat in
absolute terms), never on textured pixels, where a model's misfit would read as noise. There the image's own
residual ``r = x − mean₁₇ₓ₁₇(x)`` is its noise (smooth differences such as vignetting or a tone shift are removed
by the local mean). An image is measured alone, not against the clean image, so a real capture and a simulation
of the same clean image are compared on equal terms even when the clean image carries noise of its own.

A measurement is a set of sums (:class:`NoiseSums`), so the sums of several images add up, and a statistic that
rests on too few pixels or lines is reported as not measurable (NaN), not computed from whatever is there.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import torch
from torch import Tensor

from camdegrade.functional.analysis.images import NOISE_HIGH_PASS, box_mean

__all__ = ["BINS", "HIGH_PASS", "LAGS", "MIN_LINES", "MIN_LINE_PIXELS", "MIN_PIXELS", "NoiseSums", "measure_set"]

#: Side of the local mean removed from the image (17×17: real noise is correlated over a few pixels; a smaller
#: window would remove part of it). Defined beside the flat masks, which read the noise's gradient on it too.
HIGH_PASS = NOISE_HIGH_PASS
#: Lags (pixels) of the spatial correlation, horizontal and vertical.
LAGS = (1, 2)
#: A row or column takes part in banding with at least this many flat pixels.
MIN_LINE_PIXELS = 50
#: A level bin, a correlation or a pooled level needs at least this many pixels to be measurable ...
MIN_PIXELS = 2000
#: ... and banding at least this many rows (columns).
MIN_LINES = 16
#: Intensity bins of the noise level (of the clean value, equal width in [0, 1]).
BINS = 8
_CLIP = 1e-6


@dataclass(frozen=True)
class NoiseSums:
    """Sums over the flat pixels of one or more images (8-bit levels). Add two with ``+``.

    Attributes:
        count: ``(3, BINS)`` pixels per channel and bin of clean value (pixels where the image clips excluded).
        square: ``(3, BINS)`` sum of ``r²``.
        lag: ``(2, len(LAGS), 3, 4)``: axis (horizontal, vertical), lag, channel, and ``(Σ r₀r₁, Σ r₀², Σ r₁², n)``
            over the ``n`` pairs of flat pixels that far apart.
        cross: ``(3, 3)`` sum of ``r_c · r_k`` over flat pixels (the channels' covariance, times the count).
        cross_count: pixels behind ``cross``.
        lines: ``(2, 3, 3)``: rows, columns; channel; ``(Σ mean², Σ mean⁴, number)`` of the per-line means of ``r``
            over lines with at least :data:`MIN_LINE_PIXELS` flat pixels.
    """

    count: Tensor
    square: Tensor
    lag: Tensor
    cross: Tensor
    cross_count: Tensor
    lines: Tensor

    @classmethod
    def zeros(cls) -> NoiseSums:
        d = torch.float64
        return cls(
            torch.zeros(3, BINS, dtype=d),
            torch.zeros(3, BINS, dtype=d),
            torch.zeros(2, len(LAGS), 3, 4, dtype=d),
            torch.zeros(3, 3, dtype=d),
            torch.zeros((), dtype=d),
            torch.zeros(2, 3, 3, dtype=d),
        )

    @classmethod
    def measure(
        cls, image: Tensor, clean: Tensor, mask: Tensor, *, clipping: Tensor | None = None, window: int = HIGH_PASS
    ) -> NoiseSums:
        """The sums of ``image`` ``(3, H, W)`` (float, [0, 1] units) on ``mask``, binned by ``clean``'s value.

        Pixels where ``clipping`` (default: ``image``) is at 0 or 1 in any channel are left out: clipped noise is
        not the camera's noise level. Pass the capture as ``clipping`` to measure a difference of two images.
        ``window``: the side of the local mean the level, correlation and channel sums take off (odd; a smaller one
        keeps less of the smooth content that flat pixels still hold, and less of a correlated noise); the line sums
        always take off :data:`HIGH_PASS` (a line's offset is kept in the share the banding fit divides by).
        """
        image = image.to(torch.float32)  # sums below are taken in float64
        residual = (image - box_mean(image, HIGH_PASS)) * 255.0
        fine = residual if window == HIGH_PASS else (image - box_mean(image, window)) * 255.0
        clipping = image if clipping is None else clipping
        usable = mask & ((clipping > _CLIP) & (clipping < 1 - _CLIP)).all(0)
        return cls(
            *_level_sums(fine, clean, usable),
            _lag_sums(fine, usable),
            *_cross_sums(fine, usable),
            _line_sums(residual, usable),
        )

    def __add__(self, other: NoiseSums) -> NoiseSums:
        return NoiseSums(*(getattr(self, f.name) + getattr(other, f.name) for f in fields(self)))

    @property
    def pixels(self) -> int:
        """Flat pixels measured (per channel, the most any channel has)."""
        return int(self.count.sum(1).max())

    def std(self, min_pixels: int = MIN_PIXELS) -> Tensor:
        """``(3, BINS)`` noise std per channel and bin of clean value, in 8-bit levels; NaN where a bin has fewer
        than ``min_pixels`` pixels."""
        return _ratio(self.square, self.count, min_pixels).sqrt()

    def pooled_std(self) -> float:
        """The noise std over every flat pixel and channel (levels); NaN when not measurable."""
        return float(_ratio(self.square.sum(), self.count.sum()).sqrt())

    def correlation(self) -> Tensor:
        """``(2, len(LAGS), 3)``: the residual's correlation with its neighbour ``lag`` pixels away, horizontally
        (axis 0) and vertically (axis 1), per channel; NaN where not measurable."""
        products, first, second, _ = self.lag.unbind(-1)
        enough = torch.minimum(first, second) > 0
        value = products / (first * second).clamp_min(1e-30).sqrt()
        pairs_measured = self.count.sum(1).max() >= MIN_PIXELS
        return torch.where(enough & pairs_measured, value, torch.nan)

    def covariance(self) -> tuple[Tensor, Tensor]:
        """``(3,)`` pooled variance and ``(2, len(LAGS), 3)`` lag covariances of the residual (levels²); NaN where
        not measurable."""
        products, _, _, pairs = self.lag.unbind(-1)
        lagged = torch.where(pairs >= MIN_PIXELS, products / pairs.clamp_min(1), torch.nan)
        return _ratio(self.square.sum(1), self.count.sum(1)), lagged

    def channel_correlation(self) -> Tensor:
        """``(3, 3)`` correlation between the channels' residuals at the same pixel (chroma noise); NaN where not
        measurable."""
        if float(self.cross_count) < MIN_PIXELS:
            return torch.full((3, 3), torch.nan, dtype=torch.float64)
        std = self.cross.diagonal().clamp_min(1e-30).sqrt()
        return self.cross / (std[:, None] * std[None, :])

    def line_variance(self) -> tuple[Tensor, Tensor]:
        """``(2, 3)`` mean square of the per-row (axis 0) and per-column (axis 1) means of the residual, in
        levels², per channel (banding plus what the noise itself leaves in a line's mean), and its standard
        error; NaN with fewer than :data:`MIN_LINES` lines."""
        total, fourth, number = self.lines.unbind(-1)
        enough = number >= MIN_LINES
        mean = total / number.clamp_min(1)
        spread = (fourth / number.clamp_min(1) - mean.pow(2)).clamp_min(0) / number.clamp_min(1)
        return torch.where(enough, mean, torch.nan), torch.where(enough, spread.sqrt(), torch.nan)

    def line_std(self) -> Tensor:
        """``(2, 3)``: std of the per-row (axis 0) and per-column (axis 1) means of the residual, in levels."""
        return self.line_variance()[0].sqrt()

    def line_count(self) -> Tensor:
        """``(2,)`` rows and columns behind :meth:`line_std`."""
        return self.lines[:, 0, 2]


def _ratio(num: Tensor, den: Tensor, min_pixels: int = MIN_PIXELS) -> Tensor:
    return torch.where(den >= min_pixels, num / den.clamp_min(1), torch.nan)


def _level_sums(residual: Tensor, clean: Tensor, usable: Tensor) -> tuple[Tensor, Tensor]:
    key = (clean.to(torch.float32)[:, usable] * BINS).long().clamp(0, BINS - 1)
    key = key + torch.arange(3)[:, None] * BINS
    values = residual[:, usable].double()
    count = torch.bincount(key.flatten(), minlength=3 * BINS).to(torch.float64)
    square = torch.bincount(key.flatten(), weights=values.pow(2).flatten(), minlength=3 * BINS)
    return count.reshape(3, BINS), square.reshape(3, BINS)


def _lag_sums(residual: Tensor, usable: Tensor) -> Tensor:
    out = torch.zeros(2, len(LAGS), 3, 4, dtype=torch.float64)
    weight = usable.to(residual.dtype)
    masked = residual * weight  # zero off the mask: a product counts only where both pixels are flat
    for index, lag in enumerate(LAGS):
        for axis, dim in ((0, -1), (1, -2)):
            size = residual.shape[dim] - lag
            first, second = masked.narrow(dim, 0, size), masked.narrow(dim, lag, size)
            both = weight.narrow(dim, 0, size) * weight.narrow(dim, lag, size)
            sums = [(first * second).sum((-2, -1)), (first.pow(2) * both).sum((-2, -1))]
            sums += [(second.pow(2) * both).sum((-2, -1)), both.sum().expand(3)]
            out[axis, index] = torch.stack(sums, 1).double()
    return out


def _cross_sums(residual: Tensor, usable: Tensor) -> tuple[Tensor, Tensor]:
    values = residual[:, usable].double()
    return values @ values.T, torch.tensor(float(values.shape[1]), dtype=torch.float64)


def _line_sums(residual: Tensor, usable: Tensor) -> Tensor:
    out = torch.zeros(2, 3, 3, dtype=torch.float64)
    weight = usable.to(torch.float64)
    masked = residual.double() * weight
    for axis, dim in ((0, 2), (1, 1)):  # rows average over columns (dim 2), columns over rows
        pixels = weight.sum(dim - 1)
        kept = pixels >= MIN_LINE_PIXELS
        means = masked.sum(dim)[:, kept] / pixels[kept]
        out[axis, :, 0] = means.pow(2).sum(1)
        out[axis, :, 1] = means.pow(4).sum(1)
        out[axis, :, 2] = float(kept.sum())
    return out


def measure_set(
    images: list[Tensor], cleans: list[Tensor], masks: list[Tensor], *, window: int = HIGH_PASS
) -> NoiseSums:
    """The pooled sums of a set of images measured against their clean images' masks (``window``: see
    :meth:`NoiseSums.measure`)."""
    total = NoiseSums.zeros()
    for image, clean, mask in zip(images, cleans, masks, strict=True):
        total = total + NoiseSums.measure(image, clean, mask, window=window)
    return total
