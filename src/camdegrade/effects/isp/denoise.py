"""ISP stage: the noise reduction a phone applies to its processed output (coring of the fine detail)."""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any, ClassVar

import torch
from torch import Tensor

from camdegrade.effects._common import scalar
from camdegrade.effects._fitting import as_pairs, grid_search, minimize
from camdegrade.effects.base import Effect, Pairs, check_range, register_effect
from camdegrade.effects.isp._detail import crop_options, detail_loss
from camdegrade.effects.linear import LinearFilter
from camdegrade.effects.optics.blur import fit_margin
from camdegrade.functional.isp.sharpen import denoise_image, faint_part, faint_part_, luma_detail
from camdegrade.functional.optics.blur import gaussian_taps

__all__ = ["Denoise"]

#: Where :meth:`Denoise.fit` starts: every sigma × threshold of this grid (threshold in [0, 1] units: 1 to 16 levels).
_GRID_SIGMAS = (0.5, 0.8, 1.2, 1.8, 2.7)
_GRID_THRESHOLDS = (0.0, 1 / 255, 2 / 255, 4 / 255, 8 / 255, 16 / 255)
#: The smallest threshold L-BFGS starts from: the fit moves the threshold through its square root, whose gradient
#: vanishes at 0.
_MIN_START_THRESHOLD = 0.002


@register_effect
class Denoise(Effect):
    """Noise reduction by coring on the sRGB values, as a camera's ISP removes grain before it sharpens:
    ``y = clip(x − faint(x − G_σ ⊛ x, threshold), 0, 1)`` (:func:`~camdegrade.functional.isp.sharpen.denoise_image`):
    detail well below ``threshold`` is smoothed away, detail well above it is kept. A phone's output has almost no
    faint fine detail (docs/results.md, *What the critic sees in a default fit*), which a least-squares network
    passes through from the clean image.

    Args:
        sigma: the Gaussian's standard deviation in pixels (the scale of the detail removed).
        threshold: the detail amplitude in [0, 1] units at which half of it is removed; 0 (the default) is neutral.
        luma: core the luma detail (R, G and B alike; the chroma detail kept) rather than each channel.

    Valid values (:meth:`check_values`): ``sigma`` from 0 to :attr:`MAX_SIGMA`, ``threshold`` from 0 to
    :attr:`MAX_THRESHOLD`.

    References:
        J. P. Rossi, "Digital techniques for reducing television noise", SMPTE Journal 87(3), 1978 (coring).
    """

    name = "denoise"
    stage = "isp"
    # Only the transfer function, as for sharpen: the diagnosis fits a candidate against the profile's noise-free
    # output, so a denoise stage could not mend a noise signature.
    explains = ("frequency",)
    fit_budget = 24
    MAX_SIGMA: ClassVar[float] = 8.0
    MAX_THRESHOLD: ClassVar[float] = 0.25
    sigma: Tensor
    threshold: Tensor

    def __init__(self, sigma: float = 1.0, threshold: float = 0.0, *, luma: bool = True) -> None:
        super().__init__()
        check_range("sigma", float(sigma), 0.0, self.MAX_SIGMA)
        check_range("threshold", float(threshold), 0.0, self.MAX_THRESHOLD)
        self.register_buffer("sigma", scalar(sigma))
        self.register_buffer("threshold", scalar(threshold))
        self.luma = bool(luma)

    def config(self) -> dict[str, Any]:
        return {"luma": self.luma}

    def check_values(self) -> None:
        super().check_values()
        check_range("sigma", self.sigma, 0.0, self.MAX_SIGMA)
        check_range("threshold", self.threshold, 0.0, self.MAX_THRESHOLD)

    def scaled(self, strength: float) -> Denoise:
        """A copy whose ``threshold`` is ``strength`` times this one's (up to :attr:`MAX_THRESHOLD`); its sigma kept."""
        out = copy.deepcopy(self)
        with torch.no_grad():
            out.threshold.mul_(max(float(strength), 0.0)).clamp_(max=self.MAX_THRESHOLD)
        return out

    def magnitude(self) -> float:
        """How strong this noise reduction is: its ``threshold`` in 8-bit levels."""
        return 255.0 * float(self.threshold)

    @classmethod
    def fit_options(cls, images: Sequence[Tensor]) -> dict[str, Any]:
        """Sigmas up to 3 px, on crops as large as the smallest image allows (16 to 64 px) rather than failing."""
        return crop_options(images, 3.0)

    def forward(self, image: Tensor, params: Mapping[str, Tensor] | None = None) -> Tensor:
        device = image.device
        return denoise_image(image, self.sigma.to(device), self.threshold.to(device), luma=self.luma)

    def forward_encoded(self, image: Tensor, params: Mapping[str, Tensor] | None = None) -> Tensor:
        """In place, without autograd: the luma's detail taken from the luma alone (one plane blurred, not three),
        its faint part taken off R, G and B alike; equal to :meth:`forward` up to float rounding."""
        threshold = float(self.threshold)
        if threshold == 0.0:
            return image
        if not self.luma or min(image.shape[-2:]) <= len(gaussian_taps(float(self.sigma))) // 2:
            return self.forward(image, params)
        faint = faint_part_(luma_detail(image, float(self.sigma)), threshold)
        return image.sub_(faint).clamp_(0.0, 1.0)

    def linear_filter(self) -> LinearFilter | None:
        """The identity at threshold 0 (it returns its input unchanged, unclamped); coring otherwise, which is not
        linear (``None``): it splits a run of composed filters."""
        return LinearFilter() if float(self.threshold) == 0.0 else None

    @classmethod
    def fit(
        cls,
        source: Pairs,
        target: Pairs,
        *,
        luma: bool = True,
        max_sigma: float = 3.0,
        crop: int = 64,
        crops_per_image: int = 4,
        align: bool = True,
        max_iter: int = 40,
    ) -> Denoise:
        """Least squares of ``denoise(source)`` against ``target`` on the most textured crops (L-BFGS from the best
        of a grid over sigma and threshold, over log sigma and the square root of the threshold). With ``align``, a
        per-pair, per-channel affine colour map is projected out of the loss. Where nothing fits better than the
        identity, threshold 0 is returned. Recovery on synthetic pairs (``tests/test_denoise.py``): the threshold
        within 20 % and sigma within 25 % for sigma 0.8–1.5 px and thresholds of 2–8 levels, also through noise and a
        colour shift; a target that is the source, or the source sharpened, gives a threshold below 0.5 levels.
        """
        margin = fit_margin(max_sigma)
        loss_of = detail_loss(
            as_pairs(source, target), crop, crops_per_image, margin, luma=luma, align=align, combine=_denoised
        )
        sigma0, threshold0 = _grid_start(loss_of, max_sigma)
        if threshold0 == 0.0:
            return cls(sigma0, 0.0, luma=luma)
        log_sigma = torch.tensor(math.log(sigma0), dtype=torch.float64, requires_grad=True)
        root = torch.tensor(max(threshold0, _MIN_START_THRESHOLD) ** 0.5, dtype=torch.float64, requires_grad=True)

        def values() -> tuple[Tensor, Tensor]:
            return log_sigma.exp().clamp(max=max_sigma), root.pow(2).clamp(max=cls.MAX_THRESHOLD)

        fitted_loss = minimize([log_sigma, root], lambda: loss_of(*values()), max_iter=max_iter)
        with torch.no_grad():
            sigma, threshold = (float(value) for value in values())
            if float(loss_of(values()[0], torch.zeros((), dtype=torch.float64))) <= fitted_loss:
                return cls(sigma, 0.0, luma=luma)
        return cls(sigma, threshold, luma=luma)


def _denoised(inner: Tensor, detail: Tensor, threshold: Tensor) -> Tensor:
    return inner - faint_part(detail, threshold)


def _grid_start(loss_of: Callable[..., Tensor], max_sigma: float) -> tuple[float, float]:
    """The best ``(sigma, threshold)`` of the grid (threshold 0 is the identity at any sigma)."""

    def loss(sigma: float, threshold: float) -> float:
        with torch.no_grad():
            return float(loss_of(*(torch.tensor(v, dtype=torch.float64) for v in (sigma, threshold))))

    sigmas = [sigma for sigma in _GRID_SIGMAS if sigma <= max_sigma] or [max_sigma]
    candidates = [(sigmas[0], 0.0)] + [(s, t) for s in sigmas for t in _GRID_THRESHOLDS if t > 0]
    best = grid_search(list(range(len(candidates))), lambda index: loss(*candidates[int(index)]))
    return candidates[int(best)]
