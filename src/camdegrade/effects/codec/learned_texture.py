"""Last stage: a small learned residual network that adds the texture no named stage makes (aliasing, codec
texture, the fine structure of processed noise), trained against the camera's own photos by a two-sample objective
(:mod:`camdegrade.fitting.two_sample`)."""

from __future__ import annotations

import copy
from collections.abc import Mapping
from typing import Any, ClassVar

import torch
import torch.nn.functional as F
from torch import Tensor

from camdegrade._support.checks import check_non_negative
from camdegrade.effects._common import batch_shape, resolve_params
from camdegrade.effects.base import Effect, check_range, register_effect
from camdegrade.functional.optics.blur import blur_image

__all__ = ["LearnedTexture", "layer_shapes"]

#: The layers, each a 3×3 convolution: (name, output channels, input channels); "width" is the config's.
LAYERS: tuple[tuple[str, int | str, int | str], ...] = (
    ("conv1", "width", 4),
    ("conv2", "width", "width"),
    ("conv3", 3, "width"),
)
#: Pixels of context on each side of an output pixel (three 3×3 convolutions).
RADIUS = len(LAYERS)
#: Slope of the leaky ReLU between the layers.
SLOPE = 0.2
#: Output rows computed at a time without autograd: the hidden planes of a 12-megapixel frame would take 0.6 GB.
STRIP_ROWS = 256


def layer_shapes(width: int) -> dict[str, tuple[int, ...]]:
    """The shape of every buffer of a stage of ``width`` hidden channels, by name."""
    shapes: dict[str, tuple[int, ...]] = {}
    for name, out, into in LAYERS:
        out_size, in_size = (width if size == "width" else int(size) for size in (out, into))
        shapes[f"{name}_weight"] = (out_size, in_size, 3, 3)
        shapes[f"{name}_bias"] = (out_size,)
    return shapes


@register_effect
class LearnedTexture(Effect):
    """``y = clip(x + r − G_σ ⊛ r, 0, 1)`` on the sRGB values, ``r = r(x, z)`` three 3×3 convolutions (leaky ReLU
    between them) of the image and a standard-normal plane ``z`` drawn per pixel, so the texture it adds is random
    where the camera's is (codec texture and aliasing whose position no model of the scene predicts) and follows the
    content where the camera's does. The input is padded once by :data:`RADIUS` pixels (edge values repeated).

    Its own low frequencies are taken out of the residual (``G_σ`` a Gaussian of ``sigma`` pixels): the stage changes
    texture only, never the colour, tone or shading the named stages fitted. On City100's unpaired split a stage
    trained without that removal shifted colours by up to 6 levels, and its high-pass part alone was closer to the
    camera (docs/results.md, *A learned texture stage*).

    Args:
        width: hidden channels (default 8: 1,099 weights and biases; 12: 2,079), from 1 to :attr:`MAX_WIDTH`.
        noise: draw ``z`` (default); without it ``z`` is 0 (the stage's deterministic centre).
        sigma: the low-pass (pixels) whose band the stage leaves alone, from 0 (none taken out) to
            :attr:`MAX_SIGMA`.
        weights: the buffers (``conv1_weight`` ``(width, 4, 3, 3)``, ``conv1_bias``, ``conv2_…``, ``conv3_…``),
            every one of them; default zeros (the identity: the output layer is zero).

    Valid values (:meth:`check_values`): every weight and bias from ``-MAX_WEIGHT`` to :attr:`MAX_WEIGHT`, ``sigma``
    from 0 to :attr:`MAX_SIGMA`.

    Not a diagnosis candidate (:attr:`Effect.candidate`): a free network can stand in for any stage, so it names
    nothing. It has no pair fitter (:meth:`Effect.fit`): it is trained by
    :func:`camdegrade.fitting.two_sample.train.fit_two_sample`.

    References:
        M. Fritsche, S. Gu, R. Timofte, "Frequency Separation for Real-World Super-Resolution", ICCV Workshops 2019.
    """

    name = "learned_texture"
    # After the codec: it learns what the whole chain leaves unmatched, in the stored image's values.
    stage = "codec"
    explains = ("frequency", "noise_correlation")
    candidate = False
    MAX_WIDTH: ClassVar[int] = 64
    MAX_WEIGHT: ClassVar[float] = 64.0
    MAX_SIGMA: ClassVar[float] = 8.0

    def __init__(
        self, width: int = 8, *, noise: bool = True, sigma: float = 1.5, weights: Mapping[str, Tensor] | None = None
    ) -> None:
        super().__init__()
        if isinstance(width, bool) or not isinstance(width, int) or not 1 <= width <= self.MAX_WIDTH:
            raise ValueError(f"width must be an integer from 1 to {self.MAX_WIDTH}, got width={width!r}")
        if not isinstance(noise, bool):
            raise TypeError(f"noise must be True or False, got noise={noise!r}")
        if isinstance(sigma, bool) or not isinstance(sigma, (int, float)):
            raise TypeError(f"sigma must be a number, got sigma={sigma!r}")
        check_range("sigma", float(sigma), 0.0, self.MAX_SIGMA)
        self.width, self.noise, self.sigma = width, noise, float(sigma)
        shapes = layer_shapes(width)
        given = dict(weights or {})
        if weights is not None and set(given) != set(shapes):
            missing, unexpected = sorted(set(shapes) - set(given)), sorted(set(given) - set(shapes))
            raise ValueError(f"weights must hold every buffer: missing {missing}, unexpected {unexpected}")
        for key, shape in shapes.items():
            value = torch.as_tensor(given[key], dtype=torch.float32).clone() if key in given else torch.zeros(shape)
            if tuple(value.shape) != shape:
                raise ValueError(f"{key} must have shape {shape}, got shape {tuple(value.shape)}")
            check_range(key, value, -self.MAX_WEIGHT, self.MAX_WEIGHT)
            self.register_buffer(key, value)

    @classmethod
    def initial(cls, width: int = 8, seed: int = 0) -> LearnedTexture:
        """Where training starts: hidden layers drawn for a leaky ReLU (He et al. 2015) from ``seed``, the output
        layer zero, so the stage starts as the identity."""
        generator = torch.Generator().manual_seed(seed)
        weights = {}
        for key, shape in layer_shapes(width).items():
            fan_in = shape[1] * 9 if len(shape) == 4 else 1
            scale = (2.0 / ((1 + SLOPE**2) * fan_in)) ** 0.5
            hidden = not key.startswith(LAYERS[-1][0]) and key.endswith("weight")
            weights[key] = torch.randn(shape, generator=generator) * scale if hidden else torch.zeros(shape)
        return cls(width, weights=weights)

    def config(self) -> dict[str, Any]:
        return {"width": self.width, "noise": self.noise, "sigma": self.sigma}

    def check_values(self) -> None:
        super().check_values()
        check_range("sigma", self.sigma, 0.0, self.MAX_SIGMA)
        for key, value in self.named_buffers():
            check_range(key, value, -self.MAX_WEIGHT, self.MAX_WEIGHT)

    def without_randomness(self) -> LearnedTexture:
        """The stage with its noise plane at 0 (it draws nothing)."""
        out = copy.deepcopy(self)
        out.noise = False
        return out

    def scaled(self, strength: float) -> LearnedTexture:
        """A copy whose residual ``r`` is ``strength`` times this one's (the output layer scaled)."""
        out = copy.deepcopy(self)
        last = LAYERS[-1][0]
        with torch.no_grad():
            for key in (f"{last}_weight", f"{last}_bias"):
                getattr(out, key).mul_(check_non_negative(strength, "strength"))
        return out

    def magnitude(self) -> float:
        """How far from the identity: the L2 norm of the output layer (the residual is linear in it; 0: none)."""
        last = LAYERS[-1][0]
        squares = [getattr(self, f"{last}_{part}").double().pow(2).sum() for part in ("weight", "bias")]
        return float(sum(squares)) ** 0.5

    def make_params(
        self, shape: torch.Size | tuple[int, ...], generator: torch.Generator | None = None
    ) -> dict[str, Tensor]:
        n, _, height, width = batch_shape(shape)
        return {"noise": torch.randn(n, 1, height, width, generator=generator)} if self.noise else {}

    def forward(self, image: Tensor, params: Mapping[str, Tensor] | None = None) -> Tensor:
        drawn = resolve_params(self, image, params)
        n, _, height, width = image.shape
        z = drawn["noise"].to(image.dtype) if self.noise else image.new_zeros(n, 1, height, width)
        planes = F.pad(torch.cat([image - 0.5, z], 1), (RADIUS,) * 4, mode="replicate")
        if image.requires_grad or height <= STRIP_ROWS:
            residual = self.residual(planes)
        else:
            strips = [
                self.residual(planes[..., top : min(top + STRIP_ROWS, height) + 2 * RADIUS, :])
                for top in range(0, height, STRIP_ROWS)
            ]
            residual = torch.cat(strips, -2)
        if self.sigma > 0:
            residual = residual - blur_image(residual, self.sigma)
        return (image + residual).clamp(0.0, 1.0)

    def residual(self, planes: Tensor) -> Tensor:
        """``r`` (before its low frequencies are taken out) on the padded planes (image − ½ and z): :data:`RADIUS`
        pixels fewer on each side."""
        hidden = planes.contiguous(memory_format=torch.channels_last)  # about 10 % faster on the CPU here
        for index, (name, _, _) in enumerate(LAYERS):
            weight = getattr(self, f"{name}_weight").to(planes.device, planes.dtype)
            bias = getattr(self, f"{name}_bias").to(planes.device, planes.dtype)
            hidden = F.conv2d(hidden, weight, bias)
            if index < len(LAYERS) - 1:
                hidden = F.leaky_relu(hidden, SLOPE)
        return hidden.contiguous()
