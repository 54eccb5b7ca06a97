"""Codec stage: JPEG compression through the real libjpeg codec."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import torch
from torch import Tensor

from camdegrade._support.pixels import unit_to_bytes
from camdegrade.effects._common import batch_shape, resolve_params, scalar
from camdegrade.effects._fitting import as_pairs
from camdegrade.effects.base import Effect, Pairs, check_range, register_effect, shown
from camdegrade.functional import jpeg_image
from camdegrade.functional.codec import check_quality

__all__ = ["JPEG"]


@register_effect
class JPEG(Effect):
    """JPEG encode/decode at ``quality`` (1–100) with libjpeg's standard tables and 4:2:0 chroma subsampling.

    A codec always loses something, even at quality 100, so the neutral stage is ``probability=0``.

    Args:
        quality: the fitted quality (a buffer, so a profile stores it); with a ``mixture``, its deterministic centre
            (:meth:`without_randomness`), e.g. the mixture's median.
        quality_jitter: per-sample integer offset drawn uniformly from ``[-quality_jitter, quality_jitter]``
            (variable-bitrate streams); results are clipped to 1–100. 0 disables it.
        probability: chance that a sample is compressed at all (per sample). 1 compresses every image.
        mixture: ``{quality: weight}``: each sample's quality drawn from these qualities with these weights
            (normalised to sum 1; a camera or a photo set that saves at several qualities), before the jitter. The
            qualities and weights are buffers (``mixture_qualities``, ``mixture_weights``); ``config()`` records how
            many there are (``mixture``). ``None`` or empty: every sample at ``quality``.
    """

    name = "jpeg"
    stage = "codec"
    explains = ("frequency", "blocks")
    fit_budget = 16
    quality: Tensor
    #: The most qualities a mixture holds (there are no more).
    MAX_MIXTURE = 100
    #: How far from 1 the mixture's weights may sum (float32 storage of weights that summed to 1).
    WEIGHT_SUM_TOLERANCE = 1e-4

    def __init__(
        self,
        quality: int = 90,
        *,
        quality_jitter: int = 0,
        probability: float = 1.0,
        mixture: Mapping[int, float] | None = None,
    ) -> None:
        super().__init__()
        check_quality(torch.tensor(float(quality)))
        whole = isinstance(quality_jitter, int) or (isinstance(quality_jitter, float) and quality_jitter.is_integer())
        if isinstance(quality_jitter, bool) or not whole or quality_jitter < 0:  # inf and NaN are not whole
            raise ValueError(f"quality_jitter must be a non-negative integer, got quality_jitter={quality_jitter!r}")
        if not 0.0 <= float(probability) <= 1.0:
            raise ValueError(f"probability must be in [0, 1], got probability={probability!r}")
        self.register_buffer("quality", scalar(float(quality)))
        self.quality_jitter = int(quality_jitter)
        self.probability = float(probability)
        if mixture:
            qualities, weights = _checked_mixture(mixture, self.MAX_MIXTURE)
            self.register_buffer("mixture_qualities", torch.tensor(qualities, dtype=torch.float32))
            self.register_buffer("mixture_weights", torch.tensor(weights, dtype=torch.float32))

    @property
    def mixture(self) -> dict[int, float]:
        """``{quality: weight}`` of the qualities samples are drawn from (empty: every sample at ``quality``)."""
        if not hasattr(self, "mixture_qualities"):
            return {}
        pairs = zip(self.mixture_qualities.tolist(), self.mixture_weights.tolist(), strict=True)
        return {int(quality): float(weight) for quality, weight in pairs}

    def config(self) -> dict[str, Any]:
        config: dict[str, Any] = {"quality_jitter": self.quality_jitter, "probability": self.probability}
        if hasattr(self, "mixture_qualities"):
            config["mixture"] = int(self.mixture_qualities.numel())
        return config

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> JPEG:
        """A stage with buffers of the shapes ``config`` describes (a mixture's values to be loaded from a state
        dict)."""
        options = dict(config)
        count = options.pop("mixture", 0)
        whole = isinstance(count, int) and not isinstance(count, bool)
        if not whole or not 0 <= count <= cls.MAX_MIXTURE:
            raise ValueError(f"mixture must be an integer from 0 to {cls.MAX_MIXTURE}, got mixture={count!r}")
        placeholder = {100 - index: 1.0 for index in range(count)}
        return cls(**options, mixture=placeholder or None)

    @classmethod
    def neutral(cls) -> JPEG:
        """Never compressed, and at quality 100 (the codec's least change) for :meth:`scaled`."""
        return cls(100, probability=0.0)

    def check_values(self) -> None:
        """Quality an integer from 1 to 100, ``quality_jitter`` from 0 to 99, ``probability`` from 0 to 1; a
        mixture's qualities integers from 1 to 100 and its weights from 0 to 1, summing to 1."""
        super().check_values()
        check_quality(self.quality)
        check_range("quality_jitter", self.quality_jitter, 0, 99)
        check_range("probability", self.probability, 0.0, 1.0)
        if hasattr(self, "mixture_qualities"):
            qualities, weights = self.mixture_qualities, self.mixture_weights
            if bool(((qualities < 1) | (qualities > 100) | (qualities != qualities.round())).any()):
                raise ValueError(
                    f"mixture_qualities must be an integer from 1 to 100, got mixture_qualities={shown(qualities)}"
                )
            check_range("mixture_weights", weights, 0.0, 1.0)
            total = float(weights.double().sum())
            if abs(total - 1.0) > self.WEIGHT_SUM_TOLERANCE:
                raise ValueError(f"mixture_weights must sum to 1, got a sum of {total:.6g}")

    def without_randomness(self) -> JPEG:
        """The fitted quality (a mixture's centre), no jitter, no mixture, and compression on or off, whichever
        ``probability`` makes likelier."""
        centre = JPEG(int(self.quality), probability=1.0 if self.probability >= 0.5 else 0.0)
        return centre.to(self.quality.device)

    def scaled(self, strength: float) -> JPEG:
        """Quality (and a mixture's qualities) moved from 100 by ``strength`` times its distance, rounded to an
        integer from 1 to 100."""
        out = super().scaled(strength)
        out.quality.copy_(out.quality.round().clamp(1, 100))
        if hasattr(out, "mixture_qualities"):
            moved = 100 + strength * (out.mixture_qualities - 100)
            out.mixture_qualities.copy_(moved.round().clamp(1, 100))
        return out

    def make_params(
        self, shape: torch.Size | tuple[int, ...], generator: torch.Generator | None = None
    ) -> dict[str, Tensor]:
        n = batch_shape(shape)[0]
        params = {}
        offset = torch.zeros(n, dtype=torch.int64)
        if hasattr(self, "mixture_qualities"):  # each sample's quality drawn from the mixture, as an offset
            cumulative = self.mixture_weights.detach().cpu().double().cumsum(0)
            drawn = torch.rand(n, generator=generator, dtype=torch.float64) * cumulative[-1]
            index = torch.searchsorted(cumulative, drawn, right=True).clamp_max(cumulative.numel() - 1)
            chosen = self.mixture_qualities.detach().cpu()[index]
            offset += (chosen - self.quality.detach().cpu()).round().long()
        if self.quality_jitter > 0:
            span = 2 * self.quality_jitter + 1
            offset += torch.randint(0, span, (n,), generator=generator) - self.quality_jitter
        if hasattr(self, "mixture_qualities") or self.quality_jitter > 0:
            params["quality_offset"] = offset
        if 0.0 < self.probability < 1.0:
            params["apply"] = torch.rand(n, generator=generator) < self.probability
        return params

    def forward(self, image: Tensor, params: Mapping[str, Tensor] | None = None) -> Tensor:
        if self.probability == 0.0:
            return image.clone()
        drawn = resolve_params(self, image, params)
        quality = self.quality.to(image.device).expand(image.shape[0])
        if "quality_offset" in drawn:
            quality = (quality + drawn["quality_offset"]).clamp(1, 100)
        if "apply" not in drawn:
            return jpeg_image(image, quality)
        apply = drawn["apply"].bool()
        out = image.clone()
        if bool(apply.any()):
            out[apply] = jpeg_image(image[apply], quality[apply])
        return out

    @classmethod
    def fit(cls, source: Pairs, target: Pairs, *, max_side: int = 512, coarse_step: int = 5) -> JPEG:
        """Search: the quality whose JPEG round trip of ``source`` is closest (MSE) to ``target``.

        Qualities 1–100 are scanned every ``coarse_step``, then every integer around the best. Large pairs are
        centre-cropped to ``max_side`` (on the 8×8 block grid, so blocks stay aligned). Recovery on synthetic
        pairs: exact at the tested qualities (stated tolerance ±5).
        """
        pairs = []
        for src, tgt in as_pairs(source, target):
            src, tgt = _block_crop(src, tgt, max_side)
            pairs.append((unit_to_bytes(src), tgt.mul(255)))

        def error(quality: int) -> float:
            return sum(float((jpeg_image(src, quality).float() - tgt).pow(2).mean()) for src, tgt in pairs)

        coarse = sorted({*range(coarse_step, 101, coarse_step), 1, 100})
        best = min(coarse, key=error)
        fine = range(max(1, best - coarse_step + 1), min(100, best + coarse_step - 1) + 1)
        return cls(min(fine, key=error))


def _checked_mixture(mixture: Mapping[int, float], most: int) -> tuple[list[float], list[float]]:
    """A mixture's qualities and weights (normalised to sum 1), or a ``ValueError`` naming what is wrong."""
    if not isinstance(mixture, Mapping):
        raise TypeError(f"mixture must be a mapping {{quality: weight}}, got {type(mixture).__name__}")
    if len(mixture) > most:
        raise ValueError(f"mixture must hold at most {most} qualities, got {len(mixture)}")
    qualities, weights = [], []
    for quality, weight in mixture.items():
        if isinstance(quality, bool) or not isinstance(quality, int) or not 1 <= quality <= 100:
            raise ValueError(f"mixture qualities must be integers from 1 to 100, got {quality!r}")
        if isinstance(weight, bool) or not isinstance(weight, (int, float)) or not math.isfinite(weight) or weight < 0:
            raise ValueError(f"mixture weights must be finite and non-negative, got {weight!r} for quality {quality}")
        qualities.append(float(quality))
        weights.append(float(weight))
    total = sum(weights)
    if total <= 0:
        raise ValueError(f"mixture weights must not all be 0, got {dict(mixture)}")
    return qualities, [weight / total for weight in weights]


def _block_crop(source: Tensor, target: Tensor, max_side: int) -> tuple[Tensor, Tensor]:
    height, width = source.shape[-2:]
    crop_h, crop_w = min(height, max_side), min(width, max_side)
    top = ((height - crop_h) // 2) // 8 * 8
    left = ((width - crop_w) // 2) // 8 * 8
    window = (..., slice(top, top + crop_h), slice(left, left + crop_w))
    return source[window], target[window]
