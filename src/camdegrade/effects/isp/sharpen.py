"""ISP stage: the sharpening a phone applies to its processed output (unsharp masking with coring)."""

from __future__ import annotations

import copy
import itertools
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any, ClassVar

import torch
from torch import Tensor

from camdegrade.effects._common import scalar
from camdegrade.effects._fitting import PairList, as_pairs, grid_search, minimize
from camdegrade.effects.base import Effect, Pairs, check_range, register_effect
from camdegrade.effects.isp._detail import crop_options, detail_loss
from camdegrade.effects.linear import DELTA, Kernel, LinearFilter
from camdegrade.effects.optics.blur import fit_margin
from camdegrade.functional.isp.sharpen import cored_, coring, luma_detail, unsharp_mask_image
from camdegrade.functional.optics.blur import gaussian_taps

__all__ = ["Sharpen"]

#: Where :meth:`Sharpen.fit` starts: every sigma × amount (threshold 0), then every threshold at the best of those.
_GRID_SIGMAS = (0.5, 0.8, 1.2, 1.8, 2.7, 4.0)
_GRID_AMOUNTS = (0.0, 0.25, 0.5, 1.0, 2.0)
_GRID_THRESHOLDS = (0.0, 0.005, 0.01, 0.02, 0.04)
#: The smallest threshold L-BFGS starts from: the fit moves the threshold through its square root, whose
#: gradient vanishes at 0.
_MIN_START_THRESHOLD = 0.002


@register_effect
class Sharpen(Effect):
    """Unsharp masking with soft coring on the sRGB values, as a camera's ISP sharpens its output:
    ``y = clip(x + amount · coring(x − G_σ ⊛ x, threshold), 0, 1)`` (:func:`~camdegrade.functional.isp.sharpen.coring`
    passes detail well above ``threshold``, zeroes detail well below it, and half of it at it).

    Args:
        sigma: the Gaussian's standard deviation in pixels (the width of the halos).
        amount: the gain of the detail; 0 (the default) is neutral.
        threshold: the coring threshold in [0, 1] units of the detail (noise below it is not amplified).
        luma: sharpen the luma (the same detail added to R, G and B, as phone ISPs do: no colour fringes)
            rather than each channel.

    Valid values (:meth:`check_values`): ``sigma`` from 0 to :attr:`MAX_SIGMA`, ``amount`` from 0 to
    :attr:`MAX_AMOUNT`, ``threshold`` from 0 to :attr:`MAX_THRESHOLD`.
    """

    name = "sharpen"
    stage = "isp"
    # Only the transfer function: the diagnosis fits a candidate against the profile's noise-free output, so a
    # sharpen stage could not mend a noise signature, and the noise families would make it a suspect there.
    explains = ("frequency",)
    fit_budget = 24
    MAX_SIGMA: ClassVar[float] = 8.0
    MAX_AMOUNT: ClassVar[float] = 8.0
    MAX_THRESHOLD: ClassVar[float] = 0.25
    sigma: Tensor
    amount: Tensor
    threshold: Tensor

    def __init__(self, sigma: float = 1.0, amount: float = 0.0, threshold: float = 0.0, *, luma: bool = True) -> None:
        super().__init__()
        check_range("sigma", float(sigma), 0.0, self.MAX_SIGMA)
        check_range("amount", float(amount), 0.0, self.MAX_AMOUNT)
        check_range("threshold", float(threshold), 0.0, self.MAX_THRESHOLD)
        for key, value in (("sigma", sigma), ("amount", amount), ("threshold", threshold)):
            self.register_buffer(key, scalar(value))
        self.luma = bool(luma)

    def config(self) -> dict[str, Any]:
        return {"luma": self.luma}

    def check_values(self) -> None:
        super().check_values()
        check_range("sigma", self.sigma, 0.0, self.MAX_SIGMA)
        check_range("amount", self.amount, 0.0, self.MAX_AMOUNT)
        check_range("threshold", self.threshold, 0.0, self.MAX_THRESHOLD)

    def scaled(self, strength: float) -> Sharpen:
        """A copy whose ``amount`` is ``strength`` times this one's (up to :attr:`MAX_AMOUNT`); its sigma and
        threshold kept (a weaker sharpening has the same halo width)."""
        out = copy.deepcopy(self)
        with torch.no_grad():
            out.amount.mul_(max(float(strength), 0.0)).clamp_(max=self.MAX_AMOUNT)
        return out

    def magnitude(self) -> float:
        """How strong this sharpening is: its ``amount``, the gain of the detail (1: detail doubled)."""
        return float(self.amount)

    @classmethod
    def fit_options(cls, images: Sequence[Tensor]) -> dict[str, Any]:
        """Sigmas up to 4 px, on crops as large as the smallest image allows (16 to 64 px) rather than failing."""
        return crop_options(images, 4.0)

    def forward(self, image: Tensor, params: Mapping[str, Tensor] | None = None) -> Tensor:
        device = image.device
        return unsharp_mask_image(
            image, self.sigma.to(device), self.amount.to(device), self.threshold.to(device), luma=self.luma
        )

    def forward_encoded(self, image: Tensor, params: Mapping[str, Tensor] | None = None) -> Tensor:
        """In place, without autograd, with ``luma``: the detail taken from the luma alone (one plane blurred, not
        three), cored and added to R, G and B alike; equal to :meth:`forward` up to float rounding. (Without coring a
        profile's plan composes the stage instead: :meth:`linear_filter`.)"""
        amount, threshold = float(self.amount), float(self.threshold)
        if not self.luma or min(image.shape[-2:]) <= len(gaussian_taps(float(self.sigma))) // 2:
            return self.forward(image, params)
        detail = luma_detail(image, float(self.sigma))
        if threshold > 0.0:
            detail = cored_(detail, threshold)
        return image.add_(detail, alpha=amount).clamp_(0.0, 1.0)

    def linear_filter(self) -> LinearFilter | None:
        """Without coring (threshold 0, or amount 0) unsharp masking is linear and shift-invariant on the sRGB
        values: ``δ + amount·(δ − G)`` on the luma (added to R, G and B alike) or on each channel, then the clamp;
        ``G`` the separable Gaussian taps its forward subtracts. With coring it is not (``None``)."""
        amount = float(self.amount)
        if amount != 0.0 and float(self.threshold) > 0.0:
            return None
        taps = gaussian_taps(float(self.sigma))
        detail = DELTA.plus(Kernel(terms=((-1.0, taps, taps),))).times(amount)
        if self.luma:
            return LinearFilter(own=DELTA, luma=detail, clamps=True)
        return LinearFilter(own=DELTA.plus(detail), clamps=True)

    @classmethod
    def fit(
        cls,
        source: Pairs,
        target: Pairs,
        *,
        luma: bool = True,
        max_sigma: float = 4.0,
        crop: int = 64,
        crops_per_image: int = 4,
        align: bool = True,
        max_iter: int = 40,
    ) -> Sharpen:
        """Least squares of ``sharpen(source)`` against ``target`` on the most textured crops (L-BFGS).

        With ``align``, a per-pair, per-channel affine colour map is projected out of the loss, so the tone shift
        of real pairs does not read as sharpening. A grid over sigma and amount, then over the threshold, starts
        L-BFGS over log sigma, amount and the square root of the threshold; where the result fits no better than
        the identity (a flat valley of strong coring), amount 0 is returned. Recovery on synthetic pairs
        (``tests/test_sharpen.py``): sigma and amount within 15 % for sigma from 0.8 to 2 px and amount from 0.3
        to 1.5, the threshold within 0.01, also through noise and a tone/colour shift; a target that is the
        source, the source plus white noise, or a blurred source gives an amount below 0.05.
        """
        margin = fit_margin(max_sigma)
        loss_of = _sharpen_loss(as_pairs(source, target), crop, crops_per_image, margin, luma=luma, align=align)
        sigma0, amount0, threshold0 = _grid_start(loss_of, max_sigma)
        log_sigma = torch.tensor(math.log(sigma0), dtype=torch.float64, requires_grad=True)
        amount = torch.tensor(amount0, dtype=torch.float64, requires_grad=True)
        root = torch.tensor(max(threshold0, _MIN_START_THRESHOLD) ** 0.5, dtype=torch.float64, requires_grad=True)

        def values() -> tuple[Tensor, Tensor, Tensor]:
            return (
                log_sigma.exp().clamp(max=max_sigma),
                amount.clamp(0.0, cls.MAX_AMOUNT),
                root.pow(2).clamp(max=cls.MAX_THRESHOLD),
            )

        fitted_loss = minimize([log_sigma, amount, root], lambda: loss_of(*values()), max_iter=max_iter)
        with torch.no_grad():
            sigma, gain, threshold = (float(value) for value in values())
            zero = torch.zeros((), dtype=torch.float64)
            if float(loss_of(values()[0], zero, zero)) <= fitted_loss:  # a flat valley: strong coring, any amount
                return cls(sigma, 0.0, 0.0, luma=luma)
        return cls(sigma, gain, threshold, luma=luma)


def _sharpen_loss(
    pairs: PairList, crop: int, crops_per_image: int, margin: int, *, luma: bool, align: bool
) -> Callable[[Tensor, Tensor, Tensor], Tensor]:
    """Mean squared error of ``sharpen(source)`` against ``target`` on the most textured crops, as a function of
    ``(sigma, amount, threshold)``; with ``align``, a per-pair affine colour map is projected out."""

    def sharpened(inner: Tensor, detail: Tensor, amount: Tensor, threshold: Tensor) -> Tensor:
        return inner + amount * coring(detail, threshold)

    return detail_loss(pairs, crop, crops_per_image, margin, luma=luma, align=align, combine=sharpened)


def _grid_start(loss_of: Callable[[Tensor, Tensor, Tensor], Tensor], max_sigma: float) -> tuple[float, float, float]:
    """The best ``(sigma, amount)`` of the grid with no coring, then the best threshold there."""

    def loss(sigma: float, amount: float, threshold: float) -> float:
        with torch.no_grad():
            values = (torch.tensor(v, dtype=torch.float64) for v in (sigma, amount, threshold))
            return float(loss_of(*values))

    sigmas = [sigma for sigma in _GRID_SIGMAS if sigma <= max_sigma] or [max_sigma]
    pairs = list(itertools.product(sigmas, _GRID_AMOUNTS))
    best = grid_search(list(range(len(pairs))), lambda index: loss(*pairs[int(index)], 0.0))
    sigma, amount = pairs[int(best)]
    threshold = grid_search(list(_GRID_THRESHOLDS), lambda value: loss(sigma, amount, value))
    return sigma, amount, threshold
