"""Every registered family measured on a pair, an image, or a set of pairs (per-pair sums kept for the bootstrap)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import Tensor

from camdegrade.measures.base import FAMILIES, NO_REFERENCE, MeasuredPair

__all__ = ["StatisticSet", "image_statistics", "pair_statistics"]


def pair_statistics(image: Tensor, clean: Tensor, mask: Tensor | None = None) -> dict[str, tuple[Tensor, Tensor]]:
    """Every paired family's sums for one image ``(3, H, W)`` against its clean image, float in [0, 1]; ``mask`` is
    the clean image's :func:`~camdegrade.functional.analysis.images.flat_mask` (computed when not given)."""
    pair = MeasuredPair(image, clean, mask)
    return {name: family.measure(pair) for name, family in FAMILIES.items()}


def image_statistics(image: Tensor) -> dict[str, Tensor]:
    """Every no-reference family's values for one ``(3, H, W)`` float image."""
    return {name: family.measure(image) for name, family in NO_REFERENCE.items()}


@dataclass
class StatisticSet:
    """Per-pair sums of every paired family for a set of images measured against the same clean images."""

    sums: dict[str, tuple[Tensor, Tensor]]

    @classmethod
    def measure(cls, images: Sequence[Tensor], cleans: Sequence[Tensor], masks: Sequence[Tensor]) -> StatisticSet:
        per_pair = [pair_statistics(x, c, m) for x, c, m in zip(images, cleans, masks, strict=True)]
        if not per_pair:
            raise ValueError("images must hold at least one image to measure statistics")
        return cls(
            {
                name: (torch.stack([p[name][0] for p in per_pair]), torch.stack([p[name][1] for p in per_pair]))
                for name in FAMILIES
            }
        )

    def __len__(self) -> int:
        return next(iter(self.sums.values()))[0].shape[0]

    def values(self, index: Tensor | None = None) -> dict[str, Tensor]:
        """Each family's statistic over the pairs (all, or the resample ``index``)."""
        out = {}
        for name, family in FAMILIES.items():
            num, den = self.sums[name]
            if index is not None:
                num, den = num[index], den[index]
            out[name] = family.reduce(num.double().sum(0), den.double().sum(0)).flatten().float()
        return out

    def compared(self, index: Tensor | None = None) -> dict[str, Tensor]:
        """:meth:`values` on the scale they are compared on (:meth:`PairedFamily.compare`)."""
        return {name: FAMILIES[name].compare(value) for name, value in self.values(index).items()}
