"""Sensor stage: a Bayer colour filter array, demosaiced by the ISP (bilinearly or edge-directed)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import ClassVar

from torch import Tensor

from camdegrade.effects._common import scalar
from camdegrade.effects._fitting import as_pairs
from camdegrade.effects.base import Effect, Pairs, check_range, register_effect
from camdegrade.functional.sensor.cfa import DEMOSAICS, PATTERNS, colour_phase_share, demosaic_image, phase_error

__all__ = ["ColorFilterArray", "sampled_share"]


@register_effect
class ColorFilterArray(Effect):
    """A Bayer sensor of ``pattern`` and its demosaicing: ``y = x + amount · (D(x) − x)``, ``D`` the mosaic of ``x``
    in linear light demosaiced by ``demosaic`` (kernel :func:`~camdegrade.functional.sensor.cfa.demosaic_image`). It
    sits with the sensor, after its noise: the noise of each site is interpolated into its neighbours, as a camera's is.

    Args:
        pattern: the layout of the 2×2 tile, one of :data:`~camdegrade.functional.sensor.cfa.PATTERNS` (``RGGB``).
        amount: 0 (the default: none) to :attr:`MAX_AMOUNT`; 1 is the full demosaic.
        demosaic: ``bilinear`` (the default) or ``edge`` (edge-directed green, bilinear colour differences; of
            :data:`~camdegrade.functional.sensor.cfa.DEMOSAICS`).

    Valid values (:meth:`check_values`): ``amount`` from 0 to :attr:`MAX_AMOUNT`; ``pattern`` a layout; ``demosaic`` a
    method.

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
    #: A fit keeps a layout only where red's error to the sources at red's sites, against blue's there, and blue's at
    #: blue's sites against red's, is at most this share (:func:`sampled_share`; a Hamilton–Adams phone 0.65, cameras
    #: without a mosaic and real pairs 0.95–1.05: docs/results.md, *A colour filter array among the default stages*).
    MAX_SAMPLED_SHARE: ClassVar[float] = 0.85
    amount: Tensor

    def __init__(self, pattern: str = "RGGB", amount: float = 0.0, demosaic: str = "bilinear") -> None:
        super().__init__()
        if not isinstance(pattern, str) or pattern not in PATTERNS:
            raise ValueError(f"pattern must be one of {tuple(PATTERNS)}, got pattern={pattern!r}")
        if not isinstance(demosaic, str) or demosaic not in DEMOSAICS:
            raise ValueError(f"demosaic must be one of {DEMOSAICS}, got demosaic={demosaic!r}")
        check_range("amount", float(amount), 0.0, self.MAX_AMOUNT)
        self.pattern = pattern
        self.demosaic = demosaic
        self.register_buffer("amount", scalar(amount))

    def check_values(self) -> None:
        super().check_values()
        check_range("amount", self.amount, 0.0, self.MAX_AMOUNT)

    def config(self) -> dict[str, str]:
        return {"pattern": self.pattern, "demosaic": self.demosaic}

    def forward(self, image: Tensor, params: Mapping[str, Tensor] | None = None) -> Tensor:
        if float(self.amount) == 0.0:
            return image.clone()
        amount = self.amount.to(image.device, image.dtype)
        return (image + amount * (demosaic_image(image, self.pattern, self.demosaic) - image)).clamp(0.0, 1.0)

    @classmethod
    def fit(cls, source: Pairs, target: Pairs) -> ColorFilterArray:
        """The layout and amount nearest the targets in squared error (:meth:`least_squares_amount` per layout).
        The neutral stage unless the targets' error to the sources shows the layout's 2×2 phase
        (:attr:`MAX_SAMPLED_SHARE`): without it, the amount only measures how much softer the targets are (a camera
        without a mosaic scores 0.7). On a foreign camera's bilinear demosaic of a clean scene (no noise) it finds
        the layout and an amount of 1 (``tests/test_cfa.py``)."""
        pairs = as_pairs(source, target)
        fits = {pattern: cls.least_squares_amount(pairs, pattern) for pattern in PATTERNS}
        pattern = min(PATTERNS, key=lambda layout: fits[layout][1])
        amount = fits[pattern][0]
        phases = sum(phase_error(t, s) for s, t in pairs) / len(pairs)
        if sampled_share(phases, pattern) > cls.MAX_SAMPLED_SHARE:
            return cls(pattern)
        return cls(pattern, amount)

    @classmethod
    def least_squares_amount(
        cls, pairs: Sequence[tuple[Tensor, Tensor]], pattern: str, demosaic: str = "bilinear"
    ) -> tuple[float, float]:
        """``(amount, squared error)``: the amount of ``pattern``'s demosaic that brings the sources of ``pairs``
        (``(source, target)``, ``(3, H, W)`` each) nearest their targets, ``Σ d·(t − s) / Σ d²`` with
        ``d = D(s) − s``, clipped to its range; and the summed squared error it leaves."""
        changes = [demosaic_image(s[None], pattern, demosaic)[0] - s for s, _ in pairs]
        along = sum(float((d * (t - s)).sum()) for d, (s, t) in zip(changes, pairs, strict=True))
        energy = sum(float(d.pow(2).sum()) for d in changes)
        amount = min(max(along / energy, 0.0), cls.MAX_AMOUNT) if energy > 0 else 0.0
        error = sum(float((s + amount * d - t).pow(2).sum()) for d, (s, t) in zip(changes, pairs, strict=True))
        return amount, error


def sampled_share(phases: Tensor, pattern: str) -> float:
    """How much less of a :func:`~camdegrade.functional.sensor.cfa.phase_error` ``(3, 2, 2)`` red and blue hold where
    ``pattern`` samples them than each other there (:func:`~camdegrade.functional.sensor.cfa.colour_phase_share`):
    0 for an exact mosaic, 1 without one, and 1 too for a phase pattern common to every channel (a resampler's, a
    JPEG grid's), which a share of red and blue alone read as a mosaic (CC15's real captures: 0.91)."""
    return colour_phase_share(phases, pattern)
