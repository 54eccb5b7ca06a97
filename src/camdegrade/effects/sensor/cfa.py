"""Sensor stage: a Bayer colour filter array, demosaiced bilinearly by the ISP."""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import torch
from torch import Tensor

from camdegrade.effects._common import scalar
from camdegrade.effects._fitting import as_pairs
from camdegrade.effects.base import Effect, Pairs, check_range, register_effect
from camdegrade.functional.sensor.cfa import PATTERNS, bayer_masks, demosaic_image, phase_error

__all__ = ["ColorFilterArray", "sampled_share"]


@register_effect
class ColorFilterArray(Effect):
    """A Bayer sensor of ``pattern`` and bilinear demosaicing: ``y = x + amount · (D(x) − x)``, ``D`` the mosaic of
    ``x`` in linear light demosaiced bilinearly (kernel :func:`~camdegrade.functional.sensor.cfa.demosaic_image`). It
    sits with the sensor, after its noise: the noise of each site is interpolated into its neighbours, as a camera's is.

    Args:
        pattern: the layout of the 2×2 tile, one of :data:`~camdegrade.functional.sensor.cfa.PATTERNS` (``RGGB``).
        amount: 0 (the default: none) to :attr:`MAX_AMOUNT`; 1 is the full demosaic.

    Valid values (:meth:`check_values`): ``amount`` from 0 to :attr:`MAX_AMOUNT`; ``pattern`` a layout.

    Not a diagnosis candidate (:attr:`Effect.candidate`): no statistic family reads its 2×2 phase yet
    (:func:`~camdegrade.functional.sensor.cfa.phase_error` does, on pairs; docs/results.md).

    References:
        B. E. Bayer, "Color imaging array", US patent 3,971,065, 1976.
    """

    name = "cfa"
    stage = "sensor"
    explains = ("noise_correlation", "frequency")
    fit_budget = 16
    candidate = False
    MAX_AMOUNT: ClassVar[float] = 2.0
    #: A fit keeps a layout only where the targets' error to the sources is at most this share, at the sites where
    #: red and blue are sampled, of what it is at their other sites (:func:`sampled_share`; a Hamilton–Adams phone
    #: 0.6–0.7, a camera without a mosaic 1.0 ± 0.02: a blur makes every phase alike).
    MAX_SAMPLED_SHARE: ClassVar[float] = 0.85
    amount: Tensor

    def __init__(self, pattern: str = "RGGB", amount: float = 0.0) -> None:
        super().__init__()
        if not isinstance(pattern, str) or pattern not in PATTERNS:
            raise ValueError(f"pattern must be one of {tuple(PATTERNS)}, got pattern={pattern!r}")
        check_range("amount", float(amount), 0.0, self.MAX_AMOUNT)
        self.pattern = pattern
        self.register_buffer("amount", scalar(amount))

    def check_values(self) -> None:
        super().check_values()
        check_range("amount", self.amount, 0.0, self.MAX_AMOUNT)

    def config(self) -> dict[str, str]:
        return {"pattern": self.pattern}

    def forward(self, image: Tensor, params: Mapping[str, Tensor] | None = None) -> Tensor:
        if float(self.amount) == 0.0:
            return image.clone()
        amount = self.amount.to(image.device, image.dtype)
        return (image + amount * (demosaic_image(image, self.pattern) - image)).clamp(0.0, 1.0)

    @classmethod
    def fit(cls, source: Pairs, target: Pairs) -> ColorFilterArray:
        """The layout and amount nearest the targets in squared error: per layout the amount by least squares
        (``Σ d·(t − s) / Σ d²``, ``d = D(s) − s``, clipped to its range). The neutral stage unless the targets show
        the layout's 2×2 phase (:attr:`MAX_SAMPLED_SHARE`): without it, the amount only measures how much softer
        the targets are (a camera without a mosaic scores 0.7). On a foreign camera's bilinear demosaic of a clean
        scene (no noise) it finds the layout and an amount of 1 (``tests/test_cfa.py``)."""
        pairs = as_pairs(source, target)

        def fitted(pattern: str) -> tuple[float, str, float]:
            changes = [demosaic_image(s[None], pattern)[0] - s for s, _ in pairs]
            along = sum(float((d * (t - s)).sum()) for d, (s, t) in zip(changes, pairs, strict=True))
            energy = sum(float(d.pow(2).sum()) for d in changes)
            amount = min(max(along / energy, 0.0), cls.MAX_AMOUNT) if energy > 0 else 0.0
            error = sum(float((s + amount * d - t).pow(2).sum()) for d, (s, t) in zip(changes, pairs, strict=True))
            return error, pattern, amount

        _, pattern, amount = min(fitted(pattern) for pattern in PATTERNS)
        phases = sum(phase_error(t, s) for s, t in pairs) / len(pairs)
        if sampled_share(phases, pattern) > cls.MAX_SAMPLED_SHARE:
            return cls(pattern)
        return cls(pattern, amount)


def sampled_share(phases: Tensor, pattern: str) -> float:
    """The mean of a :func:`~camdegrade.functional.sensor.cfa.phase_error` ``(3, 2, 2)`` at the phases where ``pattern``
    samples red and blue, over its mean at their other phases (0: an exact mosaic; 1: no phase at all)."""
    masks = bayer_masks(2, 2, pattern).bool()
    sampled = torch.stack([phases[c][masks[c]].mean() for c in (0, 2)]).mean()
    other = torch.stack([phases[c][~masks[c]].mean() for c in (0, 2)]).mean()
    return float(sampled / other.clamp_min(1e-12))
