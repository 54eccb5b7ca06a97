"""Tone kernel: a monotone curve made of exposure (in linear light), black/white levels and a gamma."""

from __future__ import annotations

import torch
from torch import Tensor

from camdegrade.functional._utils import ParamLike, apply_float, as_channel_view, check_image, per_sample
from camdegrade.functional.isp.color import linear_to_srgb, linear_to_srgb_, srgb_to_linear, srgb_to_linear_

__all__ = ["curve_parameters", "exposed_", "levels_gamma_", "tone_curve", "tone_curve_image"]


def tone_curve_image(
    image: Tensor,
    gamma: ParamLike = 1.0,
    black: ParamLike = 0.0,
    white: ParamLike = 1.0,
    exposure: ParamLike = 0.0,
) -> Tensor:
    """Apply the curve ``y = clip((e(x) − black) / (white − black), 0, 1) ** gamma``.

    ``e(x) = srgb(2**exposure · lin(x))`` applies the exposure in linear light.

    Args:
        image: ``[..., 3, H, W]`` uint8 or float in [0, 1] (sRGB-encoded).
        gamma: exponent (> 0); above 1 darkens the mid-tones. Neutral 1.
        black: input level mapped to 0 (crushes shadows when > 0). Neutral 0.
        white: input level mapped to 1 (clips highlights when < 1); must exceed ``black``. Neutral 1.
        exposure: gain in stops (EV) applied in linear light before the levels. Neutral 0.

    Every parameter is a scalar or per-sample ``(N,)``. The curve is monotone non-decreasing in ``x``.
    """
    check_image(image)
    values = curve_parameters(image, gamma, black, white, exposure)
    return apply_float(image, lambda x: tone_curve(x, *values))


def curve_parameters(
    image: Tensor, gamma: ParamLike, black: ParamLike, white: ParamLike, exposure: ParamLike
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """The curve's ``(gamma, black, white, exposure)`` for ``image``'s samples, each viewed to broadcast over its
    channels and pixels; ``ValueError`` for a gamma not above 0 or a white not above black."""
    gamma_t, black_t, white_t, exposure_t = (
        as_channel_view(per_sample(value, image, name))
        for value, name in ((gamma, "gamma"), (black, "black"), (white, "white"), (exposure, "exposure"))
    )
    if bool((gamma_t <= 0).any()):
        raise ValueError(f"gamma must be positive, got gamma={gamma_t[gamma_t <= 0].flatten()[0].item():g}")
    if bool((white_t - black_t <= 0).any()):
        raise ValueError("white must be greater than black for every sample, got white <= black")
    return gamma_t, black_t, white_t, exposure_t


def tone_curve(x: Tensor, gamma: Tensor, black: Tensor, white: Tensor, exposure: Tensor) -> Tensor:
    """The curve of :func:`tone_curve_image` on float values of any shape (broadcasting; differentiable)."""
    if not any(t.requires_grad for t in (x, gamma, black, white, exposure)):
        return levels_gamma_(exposed_(x.clamp(0.0, 1.0), exposure), gamma, black, white)
    exposed = linear_to_srgb(srgb_to_linear(x) * torch.exp2(exposure))
    levels = ((exposed - black) / (white - black)).clamp(0.0, 1.0)
    # 0 ** gamma has an undefined gradient in gamma; keep the graph finite at black pixels.
    powered = levels.clamp_min(1e-12) ** gamma
    return torch.where(levels > 0, powered, torch.zeros_like(powered))


def exposed_(x: Tensor, exposure: Tensor, *, linear_input: bool = False) -> Tensor:
    """In place: sRGB values of ``2**exposure`` times the linear light of ``x`` (``x`` linear if ``linear_input``)."""
    if not linear_input:
        if not bool((exposure != 0).any()):
            return x
        srgb_to_linear_(x)
    return linear_to_srgb_(x.mul_(torch.exp2(exposure)))


#: Gammas from this one up lift black to at most ``tiny ** gamma`` (3e-10 in float32) instead of exactly 0.
_LIFT_BLACK_FROM_GAMMA = 0.25


def levels_gamma_(x: Tensor, gamma: Tensor, black: Tensor, white: Tensor) -> Tensor:
    """In place: ``clip((x − black) / (white − black), 0, 1) ** gamma`` (no autograd).

    ``x ** gamma`` runs as ``exp2(gamma · log2 x)``. On the CPU, log2 takes a path several times slower when any
    value is exactly 0, so for gammas of at least 0.25 black is clipped to the smallest normal float instead of 0
    and comes out at most 3e-10 (float32), far below any quantisation step. Smaller gammas keep an exact black:
    log2 0 = −inf and exp2(−inf) = 0.
    """
    smallest, largest = gamma.aminmax()
    smallest, largest = float(smallest), float(largest)
    powered = smallest != 1.0 or largest != 1.0
    floor = torch.finfo(x.dtype).tiny if powered and smallest >= _LIFT_BLACK_FROM_GAMMA else 0.0
    x.sub_(black).div_(white - black).clamp_(floor, 1.0)
    if powered:
        x.log2_().mul_(gamma).exp2_()
    return x
