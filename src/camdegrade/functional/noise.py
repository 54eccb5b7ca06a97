"""Sensor-noise kernel: heteroscedastic Poisson–Gaussian noise in linear light, plus optional row banding."""

from __future__ import annotations

import torch
from torch import Tensor

from camdegrade.functional._utils import ParamLike, apply_float, check_image, per_sample
from camdegrade.functional.color import linear_to_srgb, linear_to_srgb_, srgb_to_linear


def channel_param(value: ParamLike, image: Tensor, name: str) -> Tensor:
    """A per-channel parameter (scalar, ``(3,)`` or per-sample ``(N, 3)``) viewed as ``(*lead, 3, 1, 1)``."""
    tensor = torch.as_tensor(value)
    if tensor.ndim == 0:
        tensor = tensor.expand(3)
    return per_sample(tensor, image, name, (3,))[..., None, None]


def poisson_gaussian_noise_image(
    image: Tensor,
    a: ParamLike,
    b: ParamLike,
    normal: Tensor,
    *,
    row_sigma: ParamLike = 0.0,
    row_normal: Tensor | None = None,
    linear: bool = True,
) -> Tensor:
    """Add noise of variance ``a · I + b`` to the intensity ``I`` (linear light by default), then re-encode.

    Args:
        image: ``[..., 3, H, W]`` uint8 or float in [0, 1] (sRGB-encoded).
        a: shot-noise (Poisson) gain; scalar, per-channel ``(3,)`` or per-sample ``(N, 3)``. Neutral 0.
        b: read-noise (Gaussian) variance, same shapes as ``a``. Neutral 0.
        normal: pre-drawn standard-normal values broadcastable to ``image.shape`` (the kernel draws nothing).
        row_sigma: standard deviation of a per-row offset (banding), same shapes as ``a``. Neutral 0.
        row_normal: pre-drawn standard normals ``[..., 3, H, 1]``; required when ``row_sigma`` is non-zero.
        linear: apply the noise in linear light (physical photon/read noise) rather than on sRGB values.

    The result is clamped to [0, 1], as a sensor's output is.
    """
    check_image(image)
    a_t = channel_param(a, image, "a")
    b_t = channel_param(b, image, "b")
    row_t = channel_param(row_sigma, image, "row_sigma")
    for name, value in (("a", a_t), ("b", b_t), ("row_sigma", row_t)):
        if bool((value < 0).any()):
            raise ValueError(f"{name} must be non-negative, got {name}={value[value < 0].flatten()[0].item():g}")
    normal = _noise_tensor(normal, image, "normal", image.shape)
    has_rows = bool((row_t > 0).any())
    if has_rows and row_normal is None:
        raise ValueError("row_normal must be given when row_sigma is non-zero, got row_normal=None")
    rows = _noise_tensor(row_normal, image, "row_normal", (*image.shape[:-1], 1)) if has_rows else None

    def kernel(x: Tensor) -> Tensor:
        intensity = srgb_to_linear(x) if linear else x
        if intensity.requires_grad:
            noisy = intensity + (a_t * intensity + b_t).clamp_min(0.0).sqrt() * normal
            noisy = (noisy if rows is None else noisy + row_t * rows).clamp(0.0, 1.0)
            return linear_to_srgb(noisy) if linear else noisy
        noisy = add_poisson_gaussian_noise_(intensity if linear else x.clone(), a_t, b_t, normal, row_t, rows)
        return linear_to_srgb_(noisy) if linear else noisy

    return apply_float(image, kernel)


def add_poisson_gaussian_noise_(
    intensity: Tensor, a: Tensor, b: Tensor, normal: Tensor, row_sigma: Tensor, row_normal: Tensor | None
) -> Tensor:
    """In place: ``intensity + sqrt(a · intensity + b) · normal + row_sigma · row_normal``, clamped to [0, 1].

    The float ``intensity`` is overwritten and returned; parameters are already shaped to broadcast (no checks).
    """
    std = torch.addcmul(b, intensity, a).clamp_min_(0.0).sqrt_()
    intensity.addcmul_(std, normal)
    if row_normal is not None:
        intensity.add_(row_normal * row_sigma)
    return intensity.clamp_(0.0, 1.0)


def _noise_tensor(value: Tensor | None, image: Tensor, name: str, shape: tuple[int, ...] | torch.Size) -> Tensor:
    if not isinstance(value, Tensor):
        raise TypeError(f"{name} must be a tensor of standard-normal draws, got {type(value).__name__}")
    try:
        fits = torch.broadcast_shapes(value.shape, tuple(shape)) == tuple(shape)
    except RuntimeError:
        fits = False
    if not fits:
        raise ValueError(f"{name} must broadcast to shape {tuple(shape)}, got shape {tuple(value.shape)}")
    return value.to(image.device)
