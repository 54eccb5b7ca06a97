"""ISP stages: the colour matrix (white balance / colour correction) and the tone curve."""

from __future__ import annotations

import copy
from collections.abc import Mapping
from typing import Any

import torch
from torch import Tensor

from camdegrade._support.checks import check_non_negative
from camdegrade.effects._common import batch_shape, resolve_params, scalar
from camdegrade.effects._fitting import as_pairs, downscale, huber_weights, minimize, robust_lstsq
from camdegrade.effects.base import Effect, Encoding, Pairs, check_range, register_effect, shown
from camdegrade.functional import color_matrix_image, srgb_to_linear, tone_curve_image
from camdegrade.functional._utils import as_channel_view, per_sample
from camdegrade.functional.isp.local_tone import local_tone_image
from camdegrade.functional.isp.tone import exposed_, levels_gamma_, tone_curve

__all__ = ["Color", "Tone"]


@register_effect
class Color(Effect):
    """A 3×3 colour matrix applied in linear light: white-balance gains on the diagonal, cross-talk off it.

    Args:
        matrix: ``(3, 3)``; the identity (default) is neutral.
        gain_jitter: standard deviation of per-sample log channel gains drawn in :meth:`make_params`
            (illuminant/white-balance variation between shots). 0 disables it.
        linear: apply the matrix in linear light (physical) rather than on sRGB values.
    """

    name = "color"
    stage = "isp"
    explains = ("spatial", "intensity", "color")
    matrix: Tensor

    def __init__(self, matrix: Tensor | None = None, *, gain_jitter: float = 0.0, linear: bool = True) -> None:
        super().__init__()
        value = torch.eye(3) if matrix is None else torch.as_tensor(matrix, dtype=torch.float32)
        if value.shape != (3, 3):
            raise ValueError(f"matrix must have shape (3, 3), got shape {tuple(value.shape)}")
        self.register_buffer("matrix", value.detach().clone().float())
        self.gain_jitter = check_non_negative(gain_jitter, "gain_jitter")
        self.linear = bool(linear)

    def config(self) -> dict[str, Any]:
        return {"gain_jitter": self.gain_jitter, "linear": self.linear}

    def check_values(self) -> None:
        """Matrix entries from -16 to 16, ``gain_jitter`` from 0 to 1."""
        super().check_values()
        check_range("matrix", self.matrix, -16.0, 16.0)
        check_range("gain_jitter", self.gain_jitter, 0.0, 1.0)

    def without_randomness(self) -> Color:
        centre = copy.deepcopy(self)
        centre.gain_jitter = 0.0
        return centre

    def make_params(
        self, shape: torch.Size | tuple[int, ...], generator: torch.Generator | None = None
    ) -> dict[str, Tensor]:
        n = batch_shape(shape)[0]
        if self.gain_jitter == 0:
            return {}
        return {"log_gain": torch.randn(n, 3, generator=generator) * self.gain_jitter}

    def forward(self, image: Tensor, params: Mapping[str, Tensor] | None = None) -> Tensor:
        return color_matrix_image(image, self._matrix(image, params), linear=self.linear)

    def encodings(self) -> tuple[Encoding, Encoding]:
        return ("linear", "linear") if self.linear else ("srgb", "srgb")

    def forward_encoded(self, image: Tensor, params: Mapping[str, Tensor] | None = None) -> Tensor:
        return color_matrix_image(image, self._matrix(image, params), linear=False)

    def _matrix(self, image: Tensor, params: Mapping[str, Tensor] | None) -> Tensor:
        drawn = resolve_params(self, image, params)
        matrix = self.matrix.to(image.device)
        if "log_gain" in drawn:
            matrix = drawn["log_gain"].exp()[:, :, None] * matrix
        return matrix

    @classmethod
    def fit(
        cls,
        source: Pairs,
        target: Pairs,
        *,
        diagonal: bool = False,
        linear: bool = True,
        max_side: int = 128,
        iterations: int = 5,
    ) -> Color:
        """Closed-form robust least squares ``target ≈ M · source`` on low-passed, unsaturated pixels.

        A colour matrix commutes with low-pass filtering in linear light, so both images are first
        area-averaged (``max_side`` pixels on the long side): this removes noise, blur and small misalignment
        from the estimate. ``iterations`` rounds of Huber reweighting discount outliers (specular
        highlights, moving objects). ``diagonal=True`` fits white-balance gains only.
        Recovery on synthetic pairs: matrix entries within 0.01 absolute.
        """
        xs, ys = [], []
        for src, tgt in as_pairs(source, target):
            if linear:
                src, tgt = srgb_to_linear(src), srgb_to_linear(tgt)
            xs.append(downscale(src, max_side).reshape(3, -1).T)
            ys.append(downscale(tgt, max_side).reshape(3, -1).T)
        x, y = torch.cat(xs).double(), torch.cat(ys).double()
        lo, hi = (0.002, 0.9) if linear else (0.02, 0.95)
        usable = ((x > lo) & (x < hi)).all(1) & ((y > lo) & (y < hi)).all(1)
        if int(usable.sum()) < 16:
            raise ValueError("too few unsaturated pixels to fit a colour matrix; use better exposed pairs")
        matrix = _robust_matrix(x[usable], y[usable], diagonal=diagonal, iterations=iterations)
        return cls(matrix.float(), linear=linear)


def _robust_matrix(x: Tensor, y: Tensor, *, diagonal: bool, iterations: int) -> Tensor:
    if not diagonal:
        return robust_lstsq(x, y, iterations).T
    weights = torch.ones(x.shape[0], dtype=x.dtype)
    matrix = torch.eye(3, dtype=x.dtype)
    for _ in range(max(1, iterations)):
        gains = (weights[:, None] * x * y).sum(0) / (weights[:, None] * x * x).sum(0).clamp_min(1e-12)
        matrix = torch.diag(gains)
        weights = huber_weights((y - x @ matrix.T).norm(dim=1))
    return matrix


@register_effect
class Tone(Effect):
    """A monotone tone curve: exposure (stops, in linear light), black/white levels, then a gamma.

    ``y = clip((srgb(2**exposure · lin(x)) − black) / (white − black), 0, 1) ** gamma``. Neutral: gamma 1,
    black 0, white 1, exposure 0. A negative ``black`` lifts the shadows and ``white > 1`` dims the highlights
    (a low-dynamic-range capture); ``black > 0`` crushes shadows and ``white < 1`` clips highlights.

    Args:
        exposure_jitter: standard deviation (stops) of a per-sample exposure offset drawn in
            :meth:`make_params` (auto-exposure variation between shots). 0 disables it.
        base_sigma: 0 (default): the curve maps every pixel (a global curve). Above 0: a local tone mapping, the
            curve applied to a base layer (each channel blurred by a Gaussian of this many pixels) and the detail
            above it carried at the curve's mean slope (:func:`~camdegrade.functional.isp.local_tone.local_tone_image`),
            so the detail a scene keeps does not depend on its brightness.
    """

    name = "tone"
    stage = "isp"
    explains = ("spatial", "intensity", "color")
    gamma: Tensor
    black: Tensor
    white: Tensor
    exposure: Tensor

    def __init__(
        self,
        gamma: float = 1.0,
        black: float = 0.0,
        white: float = 1.0,
        exposure: float = 0.0,
        *,
        exposure_jitter: float = 0.0,
        base_sigma: float = 0.0,
    ) -> None:
        super().__init__()
        if not float(gamma) > 0:
            raise ValueError(f"gamma must be positive, got gamma={float(gamma)!r}")
        if not float(white) > float(black):
            raise ValueError(f"white must be greater than black, got black={float(black)!r}, white={float(white)!r}")
        for key, value in (("gamma", gamma), ("black", black), ("white", white), ("exposure", exposure)):
            self.register_buffer(key, scalar(value))
        self.exposure_jitter = check_non_negative(exposure_jitter, "exposure_jitter")
        self.base_sigma = check_non_negative(base_sigma, "base_sigma")

    def config(self) -> dict[str, Any]:
        local = {"base_sigma": self.base_sigma} if self.base_sigma > 0 else {}
        return {"exposure_jitter": self.exposure_jitter, **local}

    def check_values(self) -> None:
        """Gamma above 0 and at most 16, levels from -16 to 16 with white above black, exposure from -16 to 16 stops,
        ``exposure_jitter`` from 0 to 4 stops, ``base_sigma`` from 0 to 64 pixels."""
        super().check_values()
        check_range("gamma", self.gamma, 0.0, 16.0, low_open=True)
        check_range("black", self.black, -16.0, 16.0)
        check_range("white", self.white, -16.0, 16.0)
        if not bool(self.white > self.black):
            raise ValueError(
                f"white must be greater than black, got black={shown(self.black)}, white={shown(self.white)}"
            )
        check_range("exposure", self.exposure, -16.0, 16.0)
        check_range("exposure_jitter", self.exposure_jitter, 0.0, 4.0)
        check_range("base_sigma", self.base_sigma, 0.0, 64.0)

    def without_randomness(self) -> Tone:
        centre = copy.deepcopy(self)
        centre.exposure_jitter = 0.0
        return centre

    def make_params(
        self, shape: torch.Size | tuple[int, ...], generator: torch.Generator | None = None
    ) -> dict[str, Tensor]:
        n = batch_shape(shape)[0]
        if self.exposure_jitter == 0:
            return {}
        return {"exposure": torch.randn(n, generator=generator) * self.exposure_jitter}

    def forward(self, image: Tensor, params: Mapping[str, Tensor] | None = None) -> Tensor:
        device = image.device
        exposure = self._exposure(image, params)
        levels = (self.gamma.to(device), self.black.to(device), self.white.to(device), exposure)
        if self.base_sigma > 0:
            return local_tone_image(image, self.base_sigma, *levels)
        return tone_curve_image(image, *levels)

    def encodings(self) -> tuple[Encoding, Encoding]:
        """Linear-light input when an exposure gain applies to a global curve (it acts on linear light), else sRGB."""
        return ("linear", "srgb") if self._has_exposure() and self.base_sigma == 0 else ("srgb", "srgb")

    def forward_encoded(self, image: Tensor, params: Mapping[str, Tensor] | None = None) -> Tensor:
        if self.base_sigma > 0:
            return self.forward(image, params)
        if self._has_exposure():
            exposure = as_channel_view(per_sample(self._exposure(image, params), image, "exposure"))
            exposed_(image, exposure, linear_input=True)
        device = image.device
        return levels_gamma_(image, self.gamma.to(device), self.black.to(device), self.white.to(device))

    def _has_exposure(self) -> bool:
        return self.exposure_jitter > 0 or bool(self.exposure != 0)

    def _exposure(self, image: Tensor, params: Mapping[str, Tensor] | None) -> Tensor:
        drawn = resolve_params(self, image, params)
        exposure = self.exposure.to(image.device)
        return exposure + drawn["exposure"] if "exposure" in drawn else exposure

    @classmethod
    def fit(
        cls,
        source: Pairs,
        target: Pairs,
        *,
        fit_exposure: bool = False,
        bins: int = 1024,
        max_iter: int = 100,
    ) -> Tone:
        """Least squares over gamma and the levels by L-BFGS on the binned pixel relation.

        The curve is pointwise and identical for the three channels, so the squared error over all pixels
        equals (up to a constant) a count-weighted squared error between the curve at each source-value bin
        and the mean target value in that bin: ``bins`` bins make the fit independent of image size, and
        zero-mean noise in the target averages out. Exposure is nearly interchangeable with the white level
        on a power-law curve, so it is held at 0 unless ``fit_exposure=True`` (then gamma and the levels
        should be fixed by other means). Recovery on synthetic pairs: gamma, black and white within 10 %.
        """
        pairs = as_pairs(source, target)
        x = torch.cat([src.reshape(-1) for src, _ in pairs]).double()
        y = torch.cat([tgt.reshape(-1) for _, tgt in pairs]).double()
        index = (x.clamp(0, 1) * (bins - 1)).round().long()
        count = torch.bincount(index, minlength=bins).double()
        used = count > 0
        weight = count[used] / count.sum()
        x = torch.bincount(index, weights=x, minlength=bins)[used] / count[used]
        y = torch.bincount(index, weights=y, minlength=bins)[used] / count[used]
        log_gamma = torch.zeros((), dtype=torch.float64, requires_grad=True)
        black = torch.zeros((), dtype=torch.float64, requires_grad=True)
        log_range = torch.zeros((), dtype=torch.float64, requires_grad=True)
        exposure = torch.zeros((), dtype=torch.float64, requires_grad=fit_exposure)
        variables = [log_gamma, black, log_range] + ([exposure] if fit_exposure else [])

        def loss() -> Tensor:
            white = black + log_range.exp()
            predicted = tone_curve(x, log_gamma.exp(), black, white, exposure)
            return (weight * (predicted - y).pow(2)).sum()

        minimize(variables, loss, max_iter=max_iter)
        with torch.no_grad():
            white = float(black + log_range.exp())
            return cls(float(log_gamma.exp()), float(black), white, float(exposure))
