"""Codec stage: JPEG compression through the real libjpeg codec."""

from __future__ import annotations

import copy
from collections.abc import Mapping
from typing import Any

import torch
from torch import Tensor

from camdegrade._pixels import unit_to_bytes
from camdegrade.effects._common import batch_shape, resolve_params, scalar
from camdegrade.effects._fitting import as_pairs
from camdegrade.effects.base import Effect, Pairs, check_range, register_effect
from camdegrade.functional import jpeg_image
from camdegrade.functional.codec import check_quality

__all__ = ["JPEG"]


@register_effect
class JPEG(Effect):
    """JPEG encode/decode at ``quality`` (1–100) with libjpeg's standard tables and 4:2:0 chroma subsampling.

    A codec always loses something, even at quality 100, so the neutral stage is ``probability=0``.

    Args:
        quality: the fitted quality (a buffer, so a profile stores it).
        quality_jitter: per-sample integer offset drawn uniformly from ``[-quality_jitter, quality_jitter]``
            (variable-bitrate streams); results are clipped to 1–100. 0 disables it.
        probability: chance that a sample is compressed at all (per sample). 1 compresses every image.
    """

    name = "jpeg"
    stage = "codec"
    explains = ("frequency", "blocks")
    fit_budget = 16
    quality: Tensor

    def __init__(self, quality: int = 90, *, quality_jitter: int = 0, probability: float = 1.0) -> None:
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

    def config(self) -> dict[str, Any]:
        return {"quality_jitter": self.quality_jitter, "probability": self.probability}

    @classmethod
    def neutral(cls) -> JPEG:
        """Never compressed, and at quality 100 (the codec's least change) for :meth:`scaled`."""
        return cls(100, probability=0.0)

    def check_values(self) -> None:
        """Quality an integer from 1 to 100, ``quality_jitter`` from 0 to 99, ``probability`` from 0 to 1."""
        super().check_values()
        check_quality(self.quality)
        check_range("quality_jitter", self.quality_jitter, 0, 99)
        check_range("probability", self.probability, 0.0, 1.0)

    def without_randomness(self) -> JPEG:
        """The fitted quality, no jitter, and compression on or off, whichever ``probability`` makes likelier."""
        centre = copy.deepcopy(self)
        centre.quality_jitter = 0
        centre.probability = 1.0 if self.probability >= 0.5 else 0.0
        return centre

    def scaled(self, strength: float) -> JPEG:
        """Quality moved from 100 by ``strength`` times its distance, rounded to an integer from 1 to 100."""
        out = super().scaled(strength)
        out.quality.copy_(out.quality.round().clamp(1, 100))
        return out

    def make_params(
        self, shape: torch.Size | tuple[int, ...], generator: torch.Generator | None = None
    ) -> dict[str, Tensor]:
        n = batch_shape(shape)[0]
        params = {}
        if self.quality_jitter > 0:
            span = 2 * self.quality_jitter + 1
            params["quality_offset"] = torch.randint(0, span, (n,), generator=generator) - self.quality_jitter
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


def _block_crop(source: Tensor, target: Tensor, max_side: int) -> tuple[Tensor, Tensor]:
    height, width = source.shape[-2:]
    crop_h, crop_w = min(height, max_side), min(width, max_side)
    top = ((height - crop_h) // 2) // 8 * 8
    left = ((width - crop_w) // 2) // 8 * 8
    window = (..., slice(top, top + crop_h), slice(left, left + crop_w))
    return source[window], target[window]
