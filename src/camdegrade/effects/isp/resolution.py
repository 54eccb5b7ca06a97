"""ISP stage: a sensor with fewer pixels than the output, its image upsampled back by the ISP (a digital upscale)."""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping
from fractions import Fraction
from typing import ClassVar

import torch
from torch import Tensor

from camdegrade.effects._common import scalar
from camdegrade.effects._fitting import as_pairs
from camdegrade.effects.base import Effect, Pairs, check_range, register_effect
from camdegrade.functional.sensor.resolution import SAMPLERS, UPSAMPLERS, resolution_image

__all__ = ["SCALES", "Resolution"]

#: The sensor resolutions :meth:`Resolution.fit` tries (besides 1): the integer reductions and the common
#: non-integer ones (720 → 1080 lines is 2/3, 960 → 1280 is 3/4). Each has a period of at most 4 pixels.
SCALES: tuple[float, ...] = (1 / 2, 1 / 3, 1 / 4, 2 / 3, 3 / 4)


@register_effect
class Resolution(Effect):
    """A sensor of ``scale`` times the output's resolution: ``y = up(down(x))``, the image reduced to ``scale`` of its
    size (``sample``) and upsampled back by the ISP's kernel ``upsample`` (kernel
    :func:`~camdegrade.functional.sensor.resolution.resolution_image`). Cheap cameras and phones in video modes output
    more pixels than they sample; the upsampling leaves a pattern locked to the sensor's grid that a convolutional
    network cannot learn, so ``fit_profile`` trains its network through this stage when it finds one.

    Args:
        scale: the sensor's resolution relative to the output, from :attr:`MIN_SCALE` to 1 (1, the default: none).
        upsample: the ISP's resampling kernel, one of :data:`~camdegrade.functional.sensor.resolution.UPSAMPLERS`
            (default ``bicubic``).
        sample: how the sensor samples, one of :data:`~camdegrade.functional.sensor.resolution.SAMPLERS`:
            ``antialiased`` (the default, a bilinear reduction without aliasing) or ``area`` (each sensor pixel the
            mean over its area: detail finer than the sensor's grid aliases, as in a camera without an optical
            low-pass filter; what a fit's sensor step uses, the network before it deciding how much detail reaches
            it).

    Valid values (:meth:`check_values`): ``scale`` from :attr:`MIN_SCALE` to 1; ``upsample`` one of the kernels;
    ``sample`` one of the samplers.

    Not a default diagnosis candidate (:attr:`Effect.candidate`): fitted after a network that has already learned
    the camera's low-pass, a second reduction blurs twice (docs/results.md, *The sensor-resolution trace*); it is
    found before the network is trained (:mod:`camdegrade.fitting.steps.resolution`).

    References:
        R. Keys, "Cubic convolution interpolation for digital image processing", IEEE TASSP 29(6), 1981.
    """

    name = "resolution"
    # The ISP's upscale, so the sensor's noise (a stage before it) is upsampled with the image, as the camera's is;
    # noise added after the upscale is too strong in the top band (docs/results.md, *lowcost-robot-sim*).
    stage = "isp"
    explains = ("frequency",)
    fit_budget = 16
    candidate = False
    MIN_SCALE: ClassVar[float] = 0.125
    scale: Tensor

    def __init__(self, scale: float = 1.0, upsample: str = "bicubic", sample: str = "antialiased") -> None:
        super().__init__()
        check_range("scale", float(scale), self.MIN_SCALE, 1.0)
        if not isinstance(upsample, str) or upsample not in UPSAMPLERS:
            raise ValueError(f"upsample must be one of {UPSAMPLERS}, got upsample={upsample!r}")
        if not isinstance(sample, str) or sample not in SAMPLERS:
            raise ValueError(f"sample must be one of {SAMPLERS}, got sample={sample!r}")
        self.upsample = upsample
        self.sample = sample
        self.register_buffer("scale", scalar(scale))

    def check_values(self) -> None:
        super().check_values()
        check_range("scale", self.scale, self.MIN_SCALE, 1.0)

    def config(self) -> dict[str, str]:
        return {"upsample": self.upsample, "sample": self.sample}

    @property
    def period(self) -> int:
        """The sensor grid's period in output pixels (the denominator of ``scale`` as a fraction, up to 64; 0.3 is
        3/10: 10 px): windows cropped at multiples of it see the pattern in the phase the whole image has."""
        return Fraction(float(self.scale)).limit_denominator(64).denominator

    def scaled(self, strength: float) -> Resolution:
        """A copy whose ``scale`` is this one's to the power ``strength`` (0: the full resolution), at least
        :attr:`MIN_SCALE`."""
        out = copy.deepcopy(self)
        with torch.no_grad():
            out.scale.pow_(max(float(strength), 0.0)).clamp_(min=self.MIN_SCALE)
        return out

    def magnitude(self) -> float:
        """How much resolution is lost: ``log2(1 / scale)`` (1 at half the resolution)."""
        return -math.log2(float(self.scale))

    def forward(self, image: Tensor, params: Mapping[str, Tensor] | None = None) -> Tensor:
        return resolution_image(image, float(self.scale), self.upsample, self.sample)

    @classmethod
    def fit(
        cls,
        source: Pairs,
        target: Pairs,
        *,
        scales: tuple[float, ...] = SCALES,
        upsamplers: tuple[str, ...] = UPSAMPLERS,
        samplers: tuple[str, ...] = SAMPLERS,
    ) -> Resolution:
        """The scale (of ``scales``, or the full resolution), the ISP's kernel (of ``upsamplers``) and the sensor's
        sampling (of ``samplers``) whose ``up(down(source))`` is nearest ``target`` in mean squared error. Exact on a
        target made by one of them (tested); on PIL's upscales of a box- or bilinear-sampled sensor it names PIL's
        kernel (its bicubic as ``catmull_rom``) and the sampling, but box and nearest are one kernel at integer
        factors (``tests/test_resampler_fit.py``). It needs the source to hold the detail the sensor lost, so after
        a fitted network it is not the way to find one (:mod:`camdegrade.fitting.steps.resolution` is)."""
        pairs = as_pairs(source, target)

        def error(choice: tuple[float, str, str]) -> float:
            return sum(float((resolution_image(s, *choice) - t).pow(2).mean()) for s, t in pairs)

        choices = [(1.0, "bicubic", "antialiased")]
        choices += [(scale, kernel, sampler) for scale in scales for kernel in upsamplers for sampler in samplers]
        return cls(*min(choices, key=error))
