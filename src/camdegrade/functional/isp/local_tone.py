"""Local tone kernel: the tone curve applied to a smooth base layer, the detail above it carried at one gain."""

from __future__ import annotations

import torch
from torch import Tensor

from camdegrade.functional._utils import ParamLike, apply_float, check_image
from camdegrade.functional.isp.tone import curve_parameters, tone_curve
from camdegrade.functional.optics.blur import blur_image

__all__ = ["local_tone_image"]


def local_tone_image(
    image: Tensor,
    sigma: float,
    gamma: ParamLike = 1.0,
    black: ParamLike = 0.0,
    white: ParamLike = 1.0,
    exposure: ParamLike = 0.0,
) -> Tensor:
    """``clip(f(base) + k · (x − base), 0, 1)``: :func:`~camdegrade.functional.isp.tone.tone_curve_image`'s curve
    ``f`` on ``base``, each channel blurred by a Gaussian of ``sigma`` pixels, and the detail ``x − base`` at the
    curve's mean slope over [0, 1], ``k = f(1) − f(0)``.

    A global curve multiplies fine detail by its slope at each pixel's brightness, so the detail it leaves depends
    on how bright the scene is; here the brightness is mapped by the curve and the detail by one gain, whatever the
    scene. ``sigma = 0`` is the global curve.

    Args:
        image: ``[..., 3, H, W]`` uint8 or float in [0, 1] (sRGB-encoded).
        sigma: the base layer's Gaussian (pixels, ≥ 0).
        gamma, black, white, exposure: the curve's, as in
            :func:`~camdegrade.functional.isp.tone.tone_curve_image` (scalars or per-sample ``(N,)``).

    References:
        F. Durand, J. Dorsey, "Fast bilateral filtering for the display of high-dynamic-range images", ACM SIGGRAPH
        2002 (a tone curve on a base layer, the detail layer kept; here the base is a Gaussian's, not a bilateral
        filter's).
    """
    check_image(image)
    if not float(sigma) >= 0:
        raise ValueError(f"sigma must be non-negative, got sigma={float(sigma)!r}")
    values = curve_parameters(image, gamma, black, white, exposure)

    def kernel(x: Tensor) -> Tensor:
        def curve(v: Tensor) -> Tensor:
            return tone_curve(v, *(t.to(v.dtype) for t in values))

        base = blur_image(x, float(sigma)) if sigma > 0 else x
        corner = x[..., :1, :1, :1]
        gain = curve(torch.ones_like(corner)) - curve(torch.zeros_like(corner))
        return (curve(base) + gain * (x - base)).clamp(0.0, 1.0)

    return apply_float(image, kernel)
