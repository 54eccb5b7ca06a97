"""Optics stage: a random local displacement of the image (jitter), whose fitted strength is how far the captures'
detail is from where the clean image puts it."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, ClassVar

import torch
from torch import Tensor

from camdegrade._support.gaussian_fields import standard_normal
from camdegrade.effects._common import batch_shape, resolve_params, scalar
from camdegrade.effects._fitting import as_pairs
from camdegrade.effects.base import Effect, Pairs, check_range, register_effect
from camdegrade.effects.optics.blur import Blur
from camdegrade.functional.analysis.coherence import coherence, displacement_sigma
from camdegrade.functional.optics.jitter import displacement_field, field_at, field_grid, jitter_image

__all__ = ["Jitter"]


@register_effect
class Jitter(Effect):
    """Every pixel read ``δ`` away, ``δ`` a smooth random field (white noise smoothed by a Gaussian of ``scale``
    pixels) of root-mean-square ``sigma`` pixels per axis, drawn anew for each image. A capture's detail is not
    exactly where the clean image puts it (a phone's multi-frame merge, a screen or print photographed, the pair's
    own registration): what a restorer trained on the simulation learns depends on it, and a paired fit's network,
    trained for the conditional mean, has already averaged it into a blur.

    Args:
        sigma: RMS shift per axis in pixels, from 0 to :attr:`MAX_SIGMA`.
        scale: the field's correlation length (the smoothing Gaussian's standard deviation) in pixels, from 1 to
            :attr:`MAX_SCALE`. Coherence does not measure it; the default is where City100's local alignment on
            tiles of 16, 32 and 64 pixels reads RMS shifts of 0.32, 0.24, 0.18 px (docs/results.md).

    Targets move with the image (:meth:`source_points`, :meth:`moved_points` read the same field).
    Its deterministic centre (:meth:`without_randomness`) is the expectation over the field, a Gaussian blur of
    ``sigma`` on the sRGB values.

    References:
        J. S. Bendat, A. G. Piersol, "Random Data: Analysis and Measurement Procedures", 4th ed., 2010, ch. 9
        (coherence); the expected phase factor of a Gaussian displacement, ``exp(−2π² f² σ²)``.
    """

    name = "jitter"
    stage = "optics"
    explains = ("alignment",)
    candidate = False
    moves_pixels = True
    #: Fixed-point steps of :meth:`moved_points`; each shrinks the error by the field's slope (below 0.3 where
    #: ``sigma ≤ MAX_SIGMA`` and ``scale ≥ 4``).
    INVERSE_STEPS: ClassVar[int] = 40
    MAX_SIGMA: ClassVar[float] = 1.5
    MAX_SCALE: ClassVar[float] = 64.0
    DEFAULT_SCALE: ClassVar[float] = 8.0
    sigma: Tensor
    scale: Tensor

    def __init__(self, sigma: float = 0.0, scale: float = DEFAULT_SCALE) -> None:
        super().__init__()
        self.register_buffer("sigma", scalar(sigma))
        self.register_buffer("scale", scalar(scale))
        self.check_values()

    def check_values(self) -> None:
        """``sigma`` from 0 to :attr:`MAX_SIGMA`, ``scale`` from 1 to :attr:`MAX_SCALE` pixels."""
        super().check_values()
        check_range("sigma", self.sigma, 0.0, self.MAX_SIGMA)
        check_range("scale", self.scale, 1.0, self.MAX_SCALE)

    def config(self) -> dict[str, Any]:
        return {}

    def magnitude(self) -> float:
        """The RMS shift per axis, in pixels."""
        return float(self.sigma)

    def scaled(self, strength: float) -> Jitter:
        return type(self)(min(float(self.sigma) * max(float(strength), 0.0), self.MAX_SIGMA), float(self.scale))

    def without_randomness(self) -> Blur:
        """The mean over the field: each pixel is read at a Gaussian offset of ``sigma`` per axis."""
        return Blur(float(self.sigma), linear=False)

    def make_params(
        self, shape: torch.Size | tuple[int, ...], generator: torch.Generator | None = None
    ) -> dict[str, Tensor]:
        n, _, height, width = batch_shape(shape)
        if float(self.sigma) == 0:
            return {}
        return {"normal": standard_normal((n, 2, *field_grid(height, width, float(self.scale))), generator)}

    def forward(self, image: Tensor, params: Mapping[str, Tensor] | None = None) -> Tensor:
        if float(self.sigma) == 0:
            return image.clone()
        field = self._field(tuple(image.shape[-2:]), resolve_params(self, image, params), image.dtype)
        if field is None:
            raise ValueError(f"params must hold the field's 'normal' draw for sigma={float(self.sigma):g}, got none")
        return jitter_image(image, field, float(self.sigma)).clamp(0.0, 1.0)

    def _field(self, size: tuple[int, int], params: Mapping[str, Tensor], dtype: torch.dtype) -> Tensor | None:
        """The drawn field over a frame of ``size``, or None where nothing moves (``sigma`` 0, nothing drawn)."""
        if float(self.sigma) == 0 or "normal" not in params:
            return None
        normal = params["normal"].to(dtype)
        if tuple(normal.shape[-2:]) != field_grid(*size, float(self.scale)):
            raise ValueError(f"params were drawn for another frame than size={tuple(size)}")
        return displacement_field(normal, self.sigma.to(dtype), float(self.scale), size)

    def source_points(
        self, x: Tensor, y: Tensor, size: tuple[int, int], params: Mapping[str, Tensor]
    ) -> tuple[Tensor, Tensor]:
        field = self._field(size, params, x.dtype)
        if field is None:
            return x, y
        shift = field_at(field, x, y)
        return x + shift[:, 1], y + shift[:, 0]

    def moved_points(
        self, x: Tensor, y: Tensor, size: tuple[int, int], params: Mapping[str, Tensor]
    ) -> tuple[Tensor, Tensor]:
        field = self._field(size, params, x.dtype)
        if field is None:
            return x, y
        moved_x, moved_y = x, y
        for _ in range(self.INVERSE_STEPS):  # q + δ(q) = p, δ smooth: a contraction
            shift = field_at(field, moved_x, moved_y)
            moved_x, moved_y = x - shift[:, 1], y - shift[:, 0]
        return moved_x, moved_y

    @classmethod
    def fit(cls, source: Pairs, target: Pairs, *, scale: float = DEFAULT_SCALE) -> Jitter:
        """The displacement that takes the coherence of ``source`` with itself (1) to its coherence with
        ``target`` (:func:`~camdegrade.functional.analysis.coherence.displacement_sigma`), ``source`` a model's
        deterministic output; 0 where too few frequencies are coherent enough to read it."""
        pairs = as_pairs(source, target)
        observed = coherence([s for s, _ in pairs], [t for _, t in pairs])
        sigma = displacement_sigma(torch.ones_like(observed), observed)
        return cls(0.0 if sigma is None or not math.isfinite(sigma) else min(sigma, cls.MAX_SIGMA), scale)
