"""Optics stage: the point-spread function (defocus/lens softness as a Gaussian, optional linear motion)."""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any, ClassVar

import torch
from torch import Tensor

from camdegrade._support.checks import check_non_negative
from camdegrade._support.fingerprint import module_tensors, tensors_fingerprint
from camdegrade.effects._common import batch_shape, resolve_params, scalar
from camdegrade.effects._fitting import PairList, affine_residual, as_pairs, grid_search, minimize, textured_crops
from camdegrade.effects.base import Effect, Encoding, Pairs, check_range, register_effect
from camdegrade.effects.linear import Kernel, LinearFilter, taps_kernel
from camdegrade.functional import blur_image, convolve_separable, psf_kernel, separable_taps

__all__ = ["Blur", "fit_margin"]


@register_effect
class Blur(Effect):
    """A PSF: a Gaussian with standard deviations ``sigma_x``/``sigma_y`` (pixels) along axes rotated by
    ``angle`` degrees, convolved with linear motion of ``motion_length`` pixels at ``motion_angle`` degrees.

    Args:
        linear: blur linear light (physical; default) rather than sRGB values.
        sigma_jitter: standard deviation of a per-sample log scale of both sigmas (focus variation between
            shots), drawn in :meth:`make_params`. 0 disables it.

    Zero sigmas and zero motion are neutral. Sigmas are in pixels of the image the stage is applied to.

    Valid values (:meth:`check_values`): sigmas from 0 to :attr:`MAX_SIGMA`, motion from 0 to :attr:`MAX_MOTION`,
    finite angles, ``sigma_jitter`` from 0 to :attr:`MAX_SIGMA_JITTER` (the kernel grows with the sigma squared).
    """

    name = "blur"
    stage = "optics"
    explains = ("frequency",)
    fit_budget = 24
    MAX_SIGMA: ClassVar[float] = 32.0
    MAX_MOTION: ClassVar[float] = 128.0
    MAX_SIGMA_JITTER: ClassVar[float] = 0.5
    sigma_x: Tensor
    sigma_y: Tensor
    angle: Tensor
    motion_length: Tensor
    motion_angle: Tensor

    def __init__(
        self,
        sigma_x: float = 0.0,
        sigma_y: float | None = None,
        angle: float = 0.0,
        motion_length: float = 0.0,
        motion_angle: float = 0.0,
        *,
        linear: bool = True,
        sigma_jitter: float = 0.0,
    ) -> None:
        super().__init__()
        sigma_y = sigma_x if sigma_y is None else sigma_y
        for key, value in (("sigma_x", sigma_x), ("sigma_y", sigma_y), ("motion_length", motion_length)):
            if not float(value) >= 0:
                raise ValueError(f"{key} must be non-negative, got {key}={float(value)!r}")
        values = {
            "sigma_x": sigma_x,
            "sigma_y": sigma_y,
            "angle": angle,
            "motion_length": motion_length,
            "motion_angle": motion_angle,
        }
        for key, value in values.items():
            self.register_buffer(key, scalar(value))
        self.linear = bool(linear)
        self.sigma_jitter = check_non_negative(sigma_jitter, "sigma_jitter")
        self._taps_cache: tuple[tuple[Any, ...], tuple[Tensor, Tensor] | None] | None = None

    def config(self) -> dict[str, Any]:
        return {"linear": self.linear, "sigma_jitter": self.sigma_jitter}

    def check_values(self) -> None:
        super().check_values()
        check_range("sigma_x", self.sigma_x, 0.0, self.MAX_SIGMA)
        check_range("sigma_y", self.sigma_y, 0.0, self.MAX_SIGMA)
        check_range("motion_length", self.motion_length, 0.0, self.MAX_MOTION)
        check_range("sigma_jitter", self.sigma_jitter, 0.0, self.MAX_SIGMA_JITTER)

    #: The buffers that say how strong the PSF is; the angles only say which way it points.
    STRENGTHS: ClassVar[tuple[str, ...]] = ("sigma_x", "sigma_y", "motion_length")

    def scaled(self, strength: float) -> Blur:
        """A copy whose sigmas and motion length are ``strength`` times these (its angles kept: a weaker blur is
        not a rotated one)."""
        out = copy.deepcopy(self)
        with torch.no_grad():
            for key in self.STRENGTHS:
                getattr(out, key).mul_(max(float(strength), 0.0))
        return out

    def magnitude(self) -> float:
        """How strong this PSF is: the L2 norm of its sigmas and motion length, in pixels (angles aside)."""
        return math.sqrt(sum(float(getattr(self, key)) ** 2 for key in self.STRENGTHS))

    def without_randomness(self) -> Blur:
        centre = copy.deepcopy(self)
        centre.sigma_jitter = 0.0
        return centre

    @classmethod
    def fit_options(cls, images: Sequence[Tensor]) -> dict[str, Any]:
        """Sigmas up to 4 px, on crops as large as the smallest image allows (16 to 64 px) rather than failing."""
        max_sigma = 4.0
        side = min(min(image.shape[-2:]) for image in images)
        return {"max_sigma": max_sigma, "crop": max(16, min(64, side - 2 * fit_margin(max_sigma)))}

    def make_params(
        self, shape: torch.Size | tuple[int, ...], generator: torch.Generator | None = None
    ) -> dict[str, Tensor]:
        n = batch_shape(shape)[0]
        if self.sigma_jitter == 0:
            return {}
        return {"sigma_scale": torch.exp(torch.randn(n, generator=generator) * self.sigma_jitter)}

    def forward(self, image: Tensor, params: Mapping[str, Tensor] | None = None) -> Tensor:
        return self._blur(image, params, linear=self.linear)

    def encodings(self) -> tuple[Encoding, Encoding]:
        return ("linear", "linear") if self.linear else ("srgb", "srgb")

    def forward_encoded(self, image: Tensor, params: Mapping[str, Tensor] | None = None) -> Tensor:
        taps = self._fixed_taps(image) if self.sigma_jitter == 0 else None
        if taps is None:
            return self._blur(image, params, linear=False)
        return convolve_separable(image, *taps)

    def linear_filter(self) -> LinearFilter | None:
        """A PSF without jitter is a linear shift-invariant filter of its encoding's values (``α`` = the PSF, nothing
        on the luma, no clamp: its taps are non-negative and sum to 1): the separable taps its forward uses where
        the PSF factorises, else the PSF's 2-D taps as separable terms. With jitter every sample has its own."""
        if self.sigma_jitter != 0:
            return None
        encoding: Encoding = "linear" if self.linear else "srgb"
        one = [value.reshape(1) for value in (self.sigma_x, self.sigma_y, self.angle, self.motion_length)]
        taps = separable_taps(*one)
        if taps is None:
            psf = psf_kernel(*one, self.motion_angle.reshape(1))[0]
            return LinearFilter(own=taps_kernel(psf), encoding=encoding)
        across, down = (tuple(float(t) for t in values[0]) for values in taps)
        return LinearFilter(own=Kernel(terms=((1.0, down, across),)), encoding=encoding)

    def _fixed_taps(self, image: Tensor) -> tuple[Tensor, Tensor] | None:
        """The separable taps of this (jitter-free) PSF for ``image``'s dtype and device, or None when it does
        not factorise; cached until a buffer changes, as building them costs more than small blurs."""
        key = (image.dtype, image.device, *tensors_fingerprint(module_tensors(self)))
        if self._taps_cache is None or self._taps_cache[0] != key:
            one = [value.reshape(1) for value in (self.sigma_x, self.sigma_y, self.angle, self.motion_length)]
            taps = separable_taps(*one)
            taps = None if taps is None else tuple(t.to(image.device, image.dtype) for t in taps)
            self._taps_cache = (key, taps)
        return self._taps_cache[1]

    def _blur(self, image: Tensor, params: Mapping[str, Tensor] | None, *, linear: bool) -> Tensor:
        drawn = resolve_params(self, image, params)
        device = image.device
        sigma_x, sigma_y = self.sigma_x.to(device), self.sigma_y.to(device)
        if "sigma_scale" in drawn:
            sigma_x, sigma_y = sigma_x * drawn["sigma_scale"], sigma_y * drawn["sigma_scale"]
        return blur_image(
            image,
            sigma_x,
            sigma_y,
            self.angle.to(device),
            self.motion_length.to(device),
            self.motion_angle.to(device),
            linear=linear,
        )

    @classmethod
    def fit(
        cls,
        source: Pairs,
        target: Pairs,
        *,
        anisotropic: bool = False,
        motion: bool = False,
        linear: bool = True,
        max_sigma: float = 6.0,
        max_motion: float = 16.0,
        crop: int = 64,
        crops_per_image: int = 4,
        align: bool = True,
        max_iter: int = 60,
    ) -> Blur:
        """Least squares of ``blur(source)`` against ``target`` on the most textured crops (L-BFGS).

        With ``align``, a per-pair, per-channel affine colour map is projected out of the loss (it commutes
        with blur), so the slight tone shift of real pairs does not read as blur. An
        isotropic sigma is initialised by a grid search, then refined together with anisotropy
        (``anisotropic``) and linear motion (``motion``). Recovery on synthetic pairs: sigma within 10 %
        for sigma from 0.8 to 3.5 pixels.
        """
        margin = fit_margin(max_sigma, max_motion if motion else None)
        loss_of = _psf_loss(as_pairs(source, target), crop, crops_per_image, margin, linear=linear, align=align)
        zero = torch.zeros((), dtype=torch.float64)

        def isotropic(sigma: float) -> float:
            with torch.no_grad():
                value = torch.tensor(sigma, dtype=torch.float64)
                return float(loss_of(value, value, zero, zero, zero))

        start = grid_search([float(s) for s in torch.logspace(-1.0, math.log10(max_sigma), 10)], isotropic)
        log_sx = torch.tensor(math.log(start), dtype=torch.float64, requires_grad=True)
        log_sy = torch.tensor(math.log(start * (1.2 if anisotropic else 1.0)), dtype=torch.float64)
        angle = torch.tensor(0.0, dtype=torch.float64)
        log_length = torch.tensor(math.log(2.0 if motion else 1e-3), dtype=torch.float64)
        direction = torch.tensor(0.0, dtype=torch.float64)
        variables = [log_sx]
        if anisotropic:
            variables += [log_sy.requires_grad_(), angle.requires_grad_()]
        if motion:
            variables += [log_length.requires_grad_(), direction.requires_grad_()]

        def sigmas() -> tuple[Tensor, Tensor]:
            sx = log_sx.exp().clamp(max=max_sigma)
            return sx, (log_sy.exp().clamp(max=max_sigma) if anisotropic else sx)

        def loss() -> Tensor:
            sx, sy = sigmas()
            length = log_length.exp().clamp(max=max_motion) if motion else zero
            return loss_of(sx, sy, angle * 45.0, length, direction * 45.0)

        if anisotropic or motion:
            _initialise_angles(loss, angle, direction, anisotropic, motion)
        minimize(variables, loss, max_iter=max_iter)
        with torch.no_grad():
            sx, sy = (float(value) for value in sigmas())
            orientation = float(angle) * 45.0 if anisotropic else 0.0
            if sy > sx:  # canonical form: sigma_x is the major axis
                sx, sy, orientation = sy, sx, orientation + 90.0
            length = float(log_length.exp().clamp(max=max_motion)) if motion else 0.0
            motion_angle = float(direction) * 45.0 % 180.0 if motion else 0.0
            return cls(sx, sy, orientation % 180.0, length, motion_angle, linear=linear)


def _psf_loss(
    pairs: PairList, crop: int, crops_per_image: int, margin: int, *, linear: bool, align: bool
) -> Callable[..., Tensor]:
    """Mean squared error of ``blur(source)`` against ``target`` on the most textured crops, as a function of the
    PSF ``(sigma_x, sigma_y, angle, motion_length, motion_angle)``; with ``align``, a per-pair affine colour map
    is projected out."""
    src, tgt, groups = textured_crops(pairs, crop, crops_per_image, margin)
    src, tgt = src.double(), tgt[..., margin:-margin, margin:-margin].double()

    def loss_of(sx: Tensor, sy: Tensor, angle: Tensor, length: Tensor, direction: Tensor) -> Tensor:
        blurred = blur_image(src, sx, sy, angle, length, direction, linear=linear)
        blurred = blurred[..., margin:-margin, margin:-margin]
        residual = affine_residual(blurred, tgt, groups=groups) if align else blurred - tgt
        return residual.pow(2).mean()

    return loss_of


def fit_margin(max_sigma: float, max_motion: float | None = None) -> int:
    """Pixels :meth:`Blur.fit` adds around each crop so that the largest PSF it tries sees real content."""
    return math.ceil(4 * max_sigma) + (math.ceil(max_motion / 2) + 2 if max_motion is not None else 1)


def _initialise_angles(
    loss: Callable[[], Tensor],
    angle: Tensor,
    direction: Tensor,
    anisotropic: bool,
    motion: bool,
) -> None:
    """Start the orientation(s) from the best of four (a symmetric start is a saddle point)."""
    best, best_loss = (0.0, 0.0), math.inf
    for quarter in range(4):
        with torch.no_grad():
            if anisotropic:
                angle.fill_(quarter)
            if motion:
                direction.fill_(quarter)
            value = float(loss())
        if value < best_loss:
            best, best_loss = (float(quarter), float(quarter)), value
    with torch.no_grad():
        angle.fill_(best[0])
        direction.fill_(best[1])
