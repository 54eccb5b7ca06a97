"""Position-dependent kernels: vignetting, radial distortion, lateral chromatic aberration and misalignment.

Radial effects use image-relative coordinates: the radius ``r`` is the distance from the image centre
divided by the half-diagonal (``r = 1`` in the corners), so one set of parameters means the same at every
resolution.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from camdegrade._support.pixels import bytes_to_unit, unit_to_bytes
from camdegrade.functional._utils import ParamLike, apply_float, check_image, flat_param, per_sample
from camdegrade.functional.isp.color import linear_to_srgb, srgb_to_linear

__all__ = [
    "centered_coordinates",
    "chromatic_aberration_image",
    "distortion_fold",
    "distortion_image",
    "distortion_source",
    "distortion_target",
    "misalignment_image",
    "misalignment_source",
    "misalignment_target",
    "radial_polynomial",
    "relative_radius",
    "remap_image",
    "remap_labels",
    "shrink_to_max_side",
    "vignetting_gain",
    "vignetting_image",
]


def centered_coordinates(height: int, width: int, dtype: torch.dtype, device: torch.device) -> tuple[Tensor, Tensor]:
    """Pixel-centre coordinates ``(x, y)``, each ``(H, W)``, in pixels from the centre (y points down)."""
    ys = torch.arange(height, dtype=dtype, device=device) + 0.5 - height / 2.0
    xs = torch.arange(width, dtype=dtype, device=device) + 0.5 - width / 2.0
    y, x = torch.meshgrid(ys, xs, indexing="ij")
    return x, y


def relative_radius(height: int, width: int, dtype: torch.dtype, device: torch.device) -> Tensor:
    """``(H, W)`` distance from the centre over the half-diagonal (0 at the centre, 1 in the corners)."""
    x, y = centered_coordinates(height, width, dtype, device)
    half_diagonal = 0.5 * (height**2 + width**2) ** 0.5
    return torch.sqrt(x**2 + y**2) / half_diagonal


def radial_polynomial(r2: Tensor, k1: Tensor, k2: Tensor) -> Tensor:
    """``1 + k1 r² + k2 r⁴`` given ``r²``: the shared form of vignetting gain and distortion scale."""
    return 1.0 + k1 * r2 + k2 * r2 * r2


def vignetting_image(image: Tensor, k1: ParamLike, k2: ParamLike = 0.0) -> Tensor:
    """Multiply linear light by the radial gain ``g(r) = max(0, 1 + k1 r² + k2 r⁴)``, then re-encode as sRGB.

    ``k1 < 0`` darkens the corners (natural vignetting); zeros are the identity. Scalars or per-sample
    ``(N,)``.
    """
    check_image(image)
    k1_t = per_sample(k1, image, "k1")[..., None, None, None]
    k2_t = per_sample(k2, image, "k2")[..., None, None, None]
    height, width = image.shape[-2:]

    def kernel(x: Tensor) -> Tensor:
        gain = vignetting_gain(height, width, k1_t, k2_t, x.dtype, x.device)
        return linear_to_srgb((srgb_to_linear(x) * gain).clamp(0.0, 1.0))

    return apply_float(image, kernel)


def vignetting_gain(
    height: int, width: int, k1: Tensor, k2: Tensor, dtype: torch.dtype, device: torch.device
) -> Tensor:
    """The gain map ``max(0, 1 + k1 r² + k2 r⁴)`` of :func:`vignetting_image` (``k1``, ``k2`` broadcast over it)."""
    r2 = relative_radius(height, width, dtype, device) ** 2
    return radial_polynomial(r2, k1, k2).clamp_min(0.0)


def remap_image(planes: Tensor, source_x: Tensor, source_y: Tensor) -> Tensor:
    """Bilinearly sample ``planes`` ``(M, C, H, W)`` at centred pixel coordinates ``(M, H, W)``.

    Samples outside the frame repeat the border.
    """
    height, width = planes.shape[-2:]
    grid = torch.stack((source_x / (width / 2.0), source_y / (height / 2.0)), dim=-1).to(planes.dtype)
    return F.grid_sample(planes, grid, mode="bilinear", padding_mode="border", align_corners=False)


def _flatten(x: Tensor) -> Tensor:
    return x.reshape(-1, *x.shape[-3:])


def distortion_image(image: Tensor, k1: ParamLike, k2: ParamLike = 0.0) -> Tensor:
    """Radial lens distortion: the output at relative position ``p`` shows the input at
    ``p · (1 + k1 r² + k2 r⁴)``.

    ``k1 > 0`` is barrel distortion (the periphery is squeezed towards the centre), ``k1 < 0`` pincushion;
    zeros are the identity. Samples outside the frame repeat the border. Scalars or per-sample ``(N,)``.
    """
    check_image(image)
    k1_t = flat_param(k1, image, "k1")[:, None, None]
    k2_t = flat_param(k2, image, "k2")[:, None, None]

    def kernel(x: Tensor) -> Tensor:
        if x.numel() == 0:
            return x.clone()
        height, width = x.shape[-2:]
        px, py = centered_coordinates(height, width, x.dtype, x.device)
        source_x, source_y = distortion_source(px, py, (height, width), k1_t.to(x.dtype), k2_t.to(x.dtype))
        return remap_image(_flatten(x), source_x, source_y).reshape(x.shape)

    return apply_float(image, kernel)


def distortion_source(x: Tensor, y: Tensor, size: tuple[int, int], k1: Tensor, k2: Tensor) -> tuple[Tensor, Tensor]:
    """Where :func:`distortion_image` reads the output positions ``(x, y)`` from: ``p · (1 + k1 r² + k2 r⁴)``.

    Positions are centred pixel coordinates (as :func:`centered_coordinates`) of an image of ``size = (H, W)``;
    ``k1`` and ``k2`` broadcast against them.
    """
    half_diagonal = 0.5 * (size[0] ** 2 + size[1] ** 2) ** 0.5
    r2 = (torch.sqrt(x**2 + y**2) / half_diagonal) ** 2
    scale = radial_polynomial(r2, k1, k2)
    return x * scale, y * scale


def distortion_target(
    x: Tensor, y: Tensor, size: tuple[int, int], k1: Tensor, k2: Tensor, iterations: int = 64
) -> tuple[Tensor, Tensor]:
    """Where :func:`distortion_image` puts the input positions ``(x, y)``: the inverse of
    :func:`distortion_source`, solving ``ρ (1 + k1 ρ² + k2 ρ⁴) = ρ_in`` for the output radius by bisection below
    :func:`distortion_fold`, where the map increases (positions, ``k1``, ``k2`` as there). A position the warp shows
    nowhere (pincushion pushes the scene's corners out of view) goes to the fold radius, outside the frame unless
    the warp folds within it."""
    half_diagonal = 0.5 * (size[0] ** 2 + size[1] ** 2) ** 0.5
    wanted = torch.sqrt(x**2 + y**2) / half_diagonal

    def radius(rho: Tensor) -> Tensor:
        return rho * radial_polynomial(rho * rho, k1, k2)

    fold = distortion_fold(k1, k2).to(wanted)
    high = torch.maximum(wanted, torch.ones_like(wanted))
    for _ in range(iterations):  # without a fold the map grows without bound: double until it passes
        high = torch.where(radius(high) < wanted, 2.0 * high, high)
    high = torch.where(torch.isfinite(fold), fold, high).expand_as(wanted)
    low = torch.zeros_like(high)
    for _ in range(iterations):
        middle = 0.5 * (low + high)
        below = radius(middle) < wanted
        low, high = torch.where(below, middle, low), torch.where(below, high, middle)
    rho = 0.5 * (low + high)
    ratio = torch.where(wanted > 0, rho / wanted.clamp_min(1e-12), torch.ones_like(wanted))
    return x * ratio, y * ratio


def distortion_fold(k1: Tensor, k2: Tensor) -> Tensor:
    """The smallest relative radius at which the radial map ``ρ (1 + k1 ρ² + k2 ρ⁴)`` of :func:`distortion_source`
    stops increasing (``inf`` where it never does): within it, every scene position shows at most once. It is the
    smallest positive root ``u`` of ``1 + 3 k1 u + 5 k2 u²`` (``u = ρ²``), written ``2 / (-b ∓ √(b² - 4a))``."""
    a, b = 5.0 * k2, 3.0 * k1
    discriminant = b * b - 4.0 * a
    root = torch.sqrt(discriminant.clamp_min(0.0))
    roots = torch.stack((2.0 / (-b - root), 2.0 / (-b + root)))
    smallest = torch.where(roots > 0, roots, torch.inf).amin(dim=0)
    return torch.sqrt(torch.where(discriminant >= 0, smallest, torch.inf))


def chromatic_aberration_image(image: Tensor, red: ParamLike, blue: ParamLike) -> Tensor:
    """Lateral chromatic aberration: the red and blue planes are magnified by ``1 + red`` and ``1 + blue``
    about the centre relative to green (e.g. ``red = 0.002`` makes the red image 0.2 % larger).

    Zeros are the identity. Scalars or per-sample ``(N,)``.
    """
    check_image(image)
    red_t = flat_param(red, image, "red")
    blue_t = flat_param(blue, image, "blue")
    magnification = 1.0 + torch.stack((red_t, torch.zeros_like(red_t), blue_t), dim=-1)  # (M, 3)
    if bool((magnification <= 0).any()):
        raise ValueError("red and blue must be greater than -1 (a positive magnification), got a value <= -1")

    def kernel(x: Tensor) -> Tensor:
        if x.numel() == 0:
            return x.clone()
        height, width = x.shape[-2:]
        px, py = centered_coordinates(height, width, x.dtype, x.device)
        inverse = (1.0 / magnification).reshape(-1, 1, 1).to(x.dtype)  # (M*3, 1, 1)
        planes = x.reshape(-1, 1, height, width)
        return remap_image(planes, px * inverse, py * inverse).reshape(x.shape)

    return apply_float(image, kernel)


def misalignment_image(image: Tensor, dx: ParamLike = 0.0, dy: ParamLike = 0.0, angle: ParamLike = 0.0) -> Tensor:
    """Move the content by ``(dx, dy)`` pixels (right, down) and rotate it by ``angle`` degrees
    counter-clockwise about the image centre, with bilinear (sub-pixel) sampling.

    Zeros are the identity. Scalars or per-sample ``(N,)``.
    """
    check_image(image)
    dx_t = flat_param(dx, image, "dx")[:, None, None]
    dy_t = flat_param(dy, image, "dy")[:, None, None]
    theta = torch.deg2rad(flat_param(angle, image, "angle"))[:, None, None]

    def kernel(x: Tensor) -> Tensor:
        if x.numel() == 0:
            return x.clone()
        height, width = x.shape[-2:]
        px, py = centered_coordinates(height, width, x.dtype, x.device)
        source_x, source_y = misalignment_source(px, py, dx_t.to(x.dtype), dy_t.to(x.dtype), theta.to(x.dtype))
        return remap_image(_flatten(x), source_x, source_y).reshape(x.shape)

    return apply_float(image, kernel)


def misalignment_source(x: Tensor, y: Tensor, dx: Tensor, dy: Tensor, theta: Tensor) -> tuple[Tensor, Tensor]:
    """Where :func:`misalignment_image` reads the output positions ``(x, y)`` (centred pixel coordinates) from:
    the shift undone, then the rotation by ``theta`` radians. ``dx``, ``dy``, ``theta`` broadcast against them."""
    qx, qy = x - dx, y - dy
    cos, sin = torch.cos(theta), torch.sin(theta)
    return qx * cos - qy * sin, qx * sin + qy * cos


def misalignment_target(x: Tensor, y: Tensor, dx: Tensor, dy: Tensor, theta: Tensor) -> tuple[Tensor, Tensor]:
    """Where :func:`misalignment_image` puts the input positions ``(x, y)``: the exact inverse of
    :func:`misalignment_source` (rotation by ``-theta``, then the shift)."""
    cos, sin = torch.cos(theta), torch.sin(theta)
    return x * cos + y * sin + dx, -x * sin + y * cos + dy


def remap_labels(labels: Tensor, source_x: Tensor, source_y: Tensor) -> Tensor:
    """``labels`` ``(..., H, W)`` (any dtype: class ids, instance ids, booleans) read at the pixel holding each of
    the centred coordinates ``(H, W)``: nearest-neighbour, so values are never mixed, and 0 where a position falls
    outside the frame. Values are gathered, not interpolated, so every dtype stays exact."""
    height, width = labels.shape[-2:]
    column = torch.floor(source_x + width / 2.0)
    row = torch.floor(source_y + height / 2.0)
    inside = (column >= 0) & (column < width) & (row >= 0) & (row < height)
    index = (row.clamp(0, height - 1) * width + column.clamp(0, width - 1)).long().flatten()
    gathered = labels.reshape(*labels.shape[:-2], height * width).index_select(-1, index).reshape(labels.shape)
    return torch.where(inside, gathered, torch.zeros((), dtype=labels.dtype, device=labels.device))


def shrink_to_max_side(image: Tensor, max_side: int | None) -> Tensor:
    """``(3, H, W)`` ``image`` downscaled (antialiased bilinear) so that its longer side is at most ``max_side``;
    the image itself when it already is (or ``max_side`` is ``None``). uint8 stays uint8, floats stay floats."""
    height, width = image.shape[-2:]
    if max_side is None or max(height, width) <= max_side:
        return image
    factor = max_side / max(height, width)
    size = (max(1, round(height * factor)), max(1, round(width * factor)))
    unit = bytes_to_unit(image) if image.dtype == torch.uint8 else image
    shrunk = F.interpolate(unit[None], size=size, mode="bilinear", antialias=True, align_corners=False)[0]
    return unit_to_bytes(shrunk, overwrite=True) if image.dtype == torch.uint8 else shrunk
