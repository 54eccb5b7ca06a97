"""Optics stages that depend on the position in the frame: vignetting, distortion, chromatic aberration and
misalignment. A translation-equivariant network cannot learn these, so they are explicit stages."""

from __future__ import annotations

import copy
from collections.abc import Mapping
from typing import Any

import torch
from torch import Tensor

from camdegrade._support.checks import check_non_negative
from camdegrade.effects._common import batch_shape, resolve_params, scalar
from camdegrade.effects._fitting import as_pairs, downscale, robust_lstsq
from camdegrade.effects.base import Effect, Encoding, Pairs, check_range, register_effect
from camdegrade.effects.optics._warp import fit_warp
from camdegrade.functional import (
    chromatic_aberration_image,
    distortion_image,
    misalignment_image,
    relative_radius,
    srgb_to_linear,
    vignetting_image,
)
from camdegrade.functional.optics.geometry import (
    distortion_fold,
    distortion_source,
    distortion_target,
    misalignment_source,
    misalignment_target,
    vignetting_gain,
)

__all__ = ["ChromaticAberration", "Distortion", "Misalignment", "Vignetting"]


@register_effect
class Vignetting(Effect):
    """Radial falloff of linear light, ``g(r) = 1 + k1 r² + k2 r⁴`` with ``r`` the relative radius (1 in the
    corners), so the same parameters hold at every resolution. ``k1 < 0`` darkens the corners; zeros are
    neutral."""

    name = "vignetting"
    stage = "optics"
    explains = ("spatial",)
    position_dependent = True
    k1: Tensor
    k2: Tensor

    def __init__(self, k1: float = 0.0, k2: float = 0.0) -> None:
        super().__init__()
        self.register_buffer("k1", scalar(k1))
        self.register_buffer("k2", scalar(k2))

    def check_values(self) -> None:
        """``k1`` and ``k2`` from -10 to 10."""
        super().check_values()
        check_range("k1", self.k1, -10.0, 10.0)
        check_range("k2", self.k2, -10.0, 10.0)

    def forward(self, image: Tensor, params: Mapping[str, Tensor] | None = None) -> Tensor:
        return vignetting_image(image, self.k1.to(image.device), self.k2.to(image.device))

    def encodings(self) -> tuple[Encoding, Encoding]:
        return ("linear", "linear")

    def forward_encoded(self, image: Tensor, params: Mapping[str, Tensor] | None = None) -> Tensor:
        height, width = image.shape[-2:]
        k1, k2 = (value.to(image.device, image.dtype) for value in (self.k1, self.k2))
        return image.mul_(vignetting_gain(height, width, k1, k2, image.dtype, image.device)).clamp_(0.0, 1.0)

    @classmethod
    def fit(
        cls, source: Pairs, target: Pairs, *, max_side: int = 64, degree: int = 2, iterations: int = 5
    ) -> Vignetting:
        """Closed form: robust least squares of the low-passed linear ratio ``target / source`` against r.

        Both images are area-averaged to ``max_side`` pixels (gain is smooth, so nothing is lost, while noise,
        blur and misalignment average out) and ``target ≈ c · source · (1 + k1 r² + k2 r⁴)`` is solved per pair
        with a free exposure ``c``; ``degree=1`` fits ``k1`` only. Pair estimates are averaged, weighted by
        their pixel counts. Recovery on synthetic pairs: ``k1`` within 10 %, the gain curve within 0.01.
        """
        if degree not in (1, 2):
            raise ValueError(f"degree must be 1 or 2, got degree={degree!r}")
        estimates, weights = [], []
        for src, tgt in as_pairs(source, target):
            low_src = downscale(srgb_to_linear(src), max_side).double()
            low_tgt = downscale(srgb_to_linear(tgt), max_side).double()
            r2 = relative_radius(*low_src.shape[-2:], torch.float64, low_src.device).pow(2).expand_as(low_src)
            usable = (low_src > 0.01) & (low_src < 0.9) & (low_tgt > 0.002) & (low_tgt < 0.95)
            if int(usable.sum()) < 3 * (degree + 1):
                continue
            s, t, r2 = low_src[usable], low_tgt[usable], r2[usable]
            columns = [s, s * r2, s * r2 * r2][: degree + 1]
            beta = robust_lstsq(torch.stack(columns, dim=1), t[:, None], iterations)[:, 0]
            estimates.append(torch.cat([beta[1:] / beta[0], torch.zeros(2 - degree, dtype=beta.dtype)]))
            weights.append(float(usable.sum()))
        if not estimates:
            raise ValueError("no pair has enough well-exposed pixels to fit vignetting")
        w = torch.tensor(weights, dtype=torch.float64)
        k = (torch.stack(estimates) * w[:, None]).sum(0) / w.sum()
        return cls(float(k[0]), float(k[1]))


@register_effect
class Distortion(Effect):
    """Radial lens distortion in relative coordinates: the output at ``p`` samples the scene at
    ``p · (1 + k1 r² + k2 r⁴)``. ``k1 > 0`` is barrel (typical of wide, cheap lenses), ``k1 < 0`` pincushion;
    zeros are neutral. It moves pixels: targets are moved by the same warp (:meth:`moved_points` inverts the
    radial polynomial; scene points pushed out of view leave the frame, and boxes and keypoints are refused where
    the warp folds within the frame)."""

    name = "distortion"
    stage = "optics"
    explains = ("alignment",)
    fit_budget = 16
    position_dependent = True
    moves_pixels = True
    k1: Tensor
    k2: Tensor

    def __init__(self, k1: float = 0.0, k2: float = 0.0) -> None:
        super().__init__()
        self.register_buffer("k1", scalar(k1))
        self.register_buffer("k2", scalar(k2))

    def check_values(self) -> None:
        """``k1`` and ``k2`` from -2 to 2 (a fisheye's ``k1`` is below 1)."""
        super().check_values()
        check_range("k1", self.k1, -2.0, 2.0)
        check_range("k2", self.k2, -2.0, 2.0)

    def forward(self, image: Tensor, params: Mapping[str, Tensor] | None = None) -> Tensor:
        return distortion_image(image, self.k1.to(image.device), self.k2.to(image.device))

    def source_points(
        self, x: Tensor, y: Tensor, size: tuple[int, int], params: Mapping[str, Tensor]
    ) -> tuple[Tensor, Tensor]:
        return distortion_source(x, y, size, self.k1.to(x), self.k2.to(x))

    def moved_points(
        self, x: Tensor, y: Tensor, size: tuple[int, int], params: Mapping[str, Tensor]
    ) -> tuple[Tensor, Tensor]:
        fold = float(distortion_fold(self.k1.double(), self.k2.double()))
        if fold < 1.0:  # relative radius 1 is the frame's corner
            raise ValueError(
                f"distortion with k1={float(self.k1):.6g}, k2={float(self.k2):.6g} folds the image within the frame "
                f"(at {fold:.3g} of the half-diagonal), so a point may show twice: boxes and keypoints cannot be "
                "moved exactly; give them as masks"
            )
        return distortion_target(x, y, size, self.k1.to(x), self.k2.to(x))

    @classmethod
    def fit(
        cls, source: Pairs, target: Pairs, *, degree: int = 1, max_side: int = 384, max_iter: int = 40
    ) -> Distortion:
        """Coarse-to-fine least squares (L-BFGS) of the warped source against the target.

        ``degree=2`` also fits ``k2`` (``k1`` and ``k2`` trade off against each other, so only fit both on
        pairs with detail out to the corners). Recovery on synthetic pairs: ``k1`` within 10 %.
        """
        if degree not in (1, 2):
            raise ValueError(f"degree must be 1 or 2, got degree={degree!r}")

        def warp(image: Tensor, k: Tensor, _: float) -> Tensor:
            return distortion_image(image, k[0], k[1] if degree == 2 else 0.0)

        k = fit_warp(as_pairs(source, target), warp, [0.0, 0.0], [0.05, 0.05], max_side=max_side, max_iter=max_iter)
        return cls(float(k[0]), float(k[1]) if degree == 2 else 0.0)


@register_effect
class ChromaticAberration(Effect):
    """Lateral chromatic aberration: red and blue planes magnified by ``1 + red`` and ``1 + blue`` about the
    centre relative to green (typical magnitudes 1e-4 to 3e-3). Zeros are neutral.

    It does not move targets (:attr:`moves_pixels` is false): green, the reference the magnifications are
    measured against and most of an image's luminance, stays where it is, and red and blue move by a fraction of
    a pixel about it (0.3 % of the distance from the centre at the most a real lens shows), so an object's mask,
    box and keypoints stay where its luminance is."""

    name = "chromatic_aberration"
    stage = "optics"
    explains = ("alignment",)
    fit_budget = 16
    position_dependent = True
    red: Tensor
    blue: Tensor

    def __init__(self, red: float = 0.0, blue: float = 0.0) -> None:
        super().__init__()
        self.register_buffer("red", scalar(red))
        self.register_buffer("blue", scalar(blue))

    def check_values(self) -> None:
        """``red`` and ``blue`` from -0.1 to 0.1 (real lenses: below 0.003)."""
        super().check_values()
        check_range("red", self.red, -0.1, 0.1)
        check_range("blue", self.blue, -0.1, 0.1)

    def forward(self, image: Tensor, params: Mapping[str, Tensor] | None = None) -> Tensor:
        return chromatic_aberration_image(image, self.red.to(image.device), self.blue.to(image.device))

    @classmethod
    def fit(cls, source: Pairs, target: Pairs, *, max_side: int = 512, max_iter: int = 40) -> ChromaticAberration:
        """Coarse-to-fine least squares (L-BFGS) of the per-channel magnifications.

        Shifts are sub-pixel, so fit at the highest affordable resolution (``max_side``). Recovery on
        synthetic pairs: within 10 %, down to 0.002 on 128-pixel images (a 0.2 pixel shift in the corners).
        """

        def warp(image: Tensor, m: Tensor, _: float) -> Tensor:
            return chromatic_aberration_image(image, m[0], m[1])

        m = fit_warp(
            as_pairs(source, target),
            warp,
            [0.0, 0.0],
            [1e-3, 1e-3],
            max_side=max_side,
            max_iter=max_iter,
            levels=(2, 1),
        )
        return cls(float(m[0]), float(m[1]))


@register_effect
class Misalignment(Effect):
    """Sub-pixel registration error between clean and captured views: a shift ``(dx, dy)`` in pixels (right,
    down) and a rotation ``angle`` in degrees (counter-clockwise) about the centre.

    Args:
        shift_std: per-sample random shift (pixels, each axis) drawn in :meth:`make_params`. 0 disables it.
        angle_std: per-sample random rotation (degrees) drawn in :meth:`make_params`. 0 disables it.

    It moves pixels: targets are moved by the same shift and rotation (the drawn ones included).
    """

    name = "misalignment"
    stage = "optics"
    explains = ("frequency", "alignment")
    fit_budget = 12
    moves_pixels = True
    dx: Tensor
    dy: Tensor
    angle: Tensor

    def __init__(
        self,
        dx: float = 0.0,
        dy: float = 0.0,
        angle: float = 0.0,
        *,
        shift_std: float = 0.0,
        angle_std: float = 0.0,
    ) -> None:
        super().__init__()
        for key, value in (("dx", dx), ("dy", dy), ("angle", angle)):
            self.register_buffer(key, scalar(value))
        self.shift_std = check_non_negative(shift_std, "shift_std")
        self.angle_std = check_non_negative(angle_std, "angle_std")

    def config(self) -> dict[str, Any]:
        return {"shift_std": self.shift_std, "angle_std": self.angle_std}

    def check_values(self) -> None:
        """Shifts from -4096 to 4096 pixels, ``angle`` from -360 to 360 degrees, ``shift_std`` from 0 to 64 pixels,
        ``angle_std`` from 0 to 45 degrees."""
        super().check_values()
        check_range("dx", self.dx, -4096.0, 4096.0)
        check_range("dy", self.dy, -4096.0, 4096.0)
        check_range("angle", self.angle, -360.0, 360.0)
        check_range("shift_std", self.shift_std, 0.0, 64.0)
        check_range("angle_std", self.angle_std, 0.0, 45.0)

    def without_randomness(self) -> Misalignment:
        centre = copy.deepcopy(self)
        centre.shift_std = centre.angle_std = 0.0
        return centre

    def make_params(
        self, shape: torch.Size | tuple[int, ...], generator: torch.Generator | None = None
    ) -> dict[str, Tensor]:
        n = batch_shape(shape)[0]
        params = {}
        if self.shift_std > 0:
            params["shift"] = torch.randn(n, 2, generator=generator) * self.shift_std
        if self.angle_std > 0:
            params["angle"] = torch.randn(n, generator=generator) * self.angle_std
        return params

    def forward(self, image: Tensor, params: Mapping[str, Tensor] | None = None) -> Tensor:
        return misalignment_image(image, *self._motion(resolve_params(self, image, params), image.device))

    def _motion(self, drawn: Mapping[str, Tensor], device: torch.device) -> tuple[Tensor, Tensor, Tensor]:
        """``(dx, dy, angle)``: the fixed values plus the drawn ones (each ``(N,)`` when drawn, else 0-d)."""
        dx, dy, angle = (value.to(device) for value in (self.dx, self.dy, self.angle))
        if "shift" in drawn:
            dx, dy = dx + drawn["shift"][:, 0].to(device), dy + drawn["shift"][:, 1].to(device)
        if "angle" in drawn:
            angle = angle + drawn["angle"].to(device)
        return dx, dy, angle

    def _motion_of_points(self, x: Tensor, params: Mapping[str, Tensor]) -> tuple[Tensor, Tensor, Tensor]:
        """:meth:`_motion` in ``x``'s dtype, shaped to broadcast over positions ``(N, P)`` (angle in radians)."""
        dx, dy, angle = (value.to(x).reshape(-1, 1) for value in self._motion(params, x.device))
        return dx, dy, torch.deg2rad(angle)

    def source_points(
        self, x: Tensor, y: Tensor, size: tuple[int, int], params: Mapping[str, Tensor]
    ) -> tuple[Tensor, Tensor]:
        return misalignment_source(x, y, *self._motion_of_points(x, params))

    def moved_points(
        self, x: Tensor, y: Tensor, size: tuple[int, int], params: Mapping[str, Tensor]
    ) -> tuple[Tensor, Tensor]:
        return misalignment_target(x, y, *self._motion_of_points(x, params))

    @classmethod
    def fit(
        cls, source: Pairs, target: Pairs, *, rotation: bool = True, max_side: int = 512, max_iter: int = 40
    ) -> Misalignment:
        """Per-pair coarse-to-fine least squares (L-BFGS) of shift (and rotation); the effect holds the mean,
        and with two or more pairs ``shift_std``/``angle_std`` hold the spread between pairs.

        Recovery on synthetic pairs: shift within 0.1 pixel, angle within 0.05 degree.
        """
        estimates = []
        for pair in as_pairs(source, target):

            def warp(image: Tensor, p: Tensor, scale: float) -> Tensor:
                return misalignment_image(image, p[0] * scale, p[1] * scale, p[2] if rotation else 0.0)

            estimates.append(
                fit_warp([pair], warp, [0.0, 0.0, 0.0], [1.0, 1.0, 0.5], max_side=max_side, max_iter=max_iter)
            )
        values = torch.stack(estimates)
        mean = values.mean(0)
        spread = values.std(0) if len(estimates) > 1 else torch.zeros(3, dtype=values.dtype)
        shift_std = float(spread[:2].pow(2).mean().sqrt())
        return cls(
            float(mean[0]),
            float(mean[1]),
            float(mean[2]),
            shift_std=shift_std,
            angle_std=float(spread[2]) if rotation else 0.0,
        )
