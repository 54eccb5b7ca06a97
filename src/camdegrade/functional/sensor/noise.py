"""Noise kernels: heteroscedastic Poisson–Gaussian noise in linear light with optional row banding, and the parts of
a camera's processed noise (a noise level by intensity, a spatially and chroma-correlated unit field, row and column
offsets). Every kernel takes pre-drawn standard normals; none draws a random number."""

from __future__ import annotations

import torch
from torch import Tensor

from camdegrade.functional._utils import ParamLike, apply_float, check_image, per_sample
from camdegrade.functional.isp.color import linear_to_srgb, linear_to_srgb_, srgb_to_linear

__all__ = [
    "add_noise_",
    "add_poisson_gaussian_noise_",
    "channel_param",
    "correlated_field",
    "interpolate_levels",
    "mix_channels",
    "noise_std",
    "poisson_gaussian_noise_image",
]


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


def correlated_field(normal: Tensor, across: Tensor, down: Tensor, mixing: Tensor | None = None) -> Tensor:
    """Noise with spatial and chroma correlation, from independent standard normals.

    Args:
        normal: standard normals ``[..., 3, H + 2r, W + 2r]`` (``r = T // 2``: a margin, so that every output pixel
            sees a full kernel and the field is stationary up to the frame's edge).
        across: ``(3, T)`` per-channel taps along x; ``down``: ``(3, T)`` along y. With taps of unit L2 norm each
            output pixel has unit variance, and the autocorrelation at lag ``d`` is ``Σ_i k_i k_{i+d}``.
        mixing: ``(3, 3)`` applied across channels (``out_c = Σ_k mixing[c, k] · field_k``); rows of unit norm keep
            unit variance and give the channel correlation ``mixing @ mixing.T``. ``None``: independent channels.

    Returns:
        ``[..., 3, H, W]`` float, in a new tensor.
    """
    taps = across.shape[-1]
    radius = taps // 2
    height, width = normal.shape[-2] - 2 * radius, normal.shape[-1] - 2 * radius
    field = _channel_taps(normal, across.to(normal), dim=-1, size=width)
    field = _channel_taps(field, down.to(normal), dim=-2, size=height)
    return field if mixing is None else mix_channels(field, mixing)


def mix_channels(planes: Tensor, mixing: Tensor) -> Tensor:
    """``out_c = Σ_k mixing[c, k] · planes_k`` over the channels of ``[..., 3, H, W]``, in a new tensor.

    Nine scaled plane additions with the matrix's entries as Python numbers (zeros skipped): on the CPU several times
    faster than ``einsum``, which runs a batched matrix product with 3×3 blocks (kept for autograd)."""
    if planes.requires_grad or mixing.requires_grad or planes.device.type != "cpu":  # no host sync on a GPU
        return torch.einsum("ck,...khw->...chw", mixing.to(planes), planes)
    weights = mixing.tolist()
    out = torch.empty_like(planes)
    for row, weight_row in enumerate(weights):
        target = out.select(-3, row)
        torch.mul(planes.select(-3, 0), weight_row[0], out=target)
        for column in (1, 2):
            if weight_row[column] != 0.0:
                target.add_(planes.select(-3, column), alpha=weight_row[column])
    return out


def _channel_taps(planes: Tensor, taps: Tensor, dim: int, size: int) -> Tensor:
    """``Σ_i taps[c, i] · planes[..., c, :, :].narrow(dim, i, size)``: a per-channel 1-D 'valid' convolution."""
    weights = taps[:, :, None, None]  # (3, T, 1, 1): broadcast over [..., 3, H, W]
    total = planes.narrow(dim, 0, size) * weights[:, 0]
    for index in range(1, taps.shape[-1]):
        total.addcmul_(planes.narrow(dim, index, size), weights[:, index])
    return total


def noise_std(x: Tensor, a: Tensor, b: Tensor, levels: Tensor | None = None) -> Tensor:
    """The noise standard deviation at each value of ``x`` ``[..., 3, H, W]``: ``sqrt(a·x + b + levels(x)²)``.

    ``a`` and ``b`` broadcast against ``x`` (e.g. ``(3, 1, 1)``); ``levels`` is ``(3, K)`` (or ``(..., 3, K)`` per
    sample): a std at each of ``K`` knots ``(k + ½) / K`` of the value, piecewise linear between them and constant
    beyond the outer knots. ``None`` leaves the table out.
    """
    variance = torch.addcmul(b, x, a)
    if levels is not None:
        table_std = interpolate_levels(x, levels)
        variance = variance.addcmul_(table_std, table_std)
    return variance.clamp_min_(0.0).sqrt_()


def interpolate_levels(x: Tensor, levels: Tensor) -> Tensor:
    """``levels`` ``(..., 3, K)`` read at each value of ``x`` ``[..., 3, H, W]`` (see :func:`noise_std`).

    Computed as a sum of hinges, ``levels[0] + Σ_k (levels[k+1] − levels[k]) · clamp(u − k, 0, 1)`` with
    ``u = x·K − ½`` the position in knot units: elementwise passes are several times faster on the CPU than a gather
    from the table, and the sum is the same piecewise-linear curve (up to float rounding)."""
    knots = levels.shape[-1]
    table = levels.to(x.dtype)[..., None, None]  # (..., 3, K, 1, 1): broadcasts against [..., 3, H, W]
    out = table[..., 0, :, :].expand(x.shape).clone()
    if knots == 1:
        return out
    steps = table[..., 1:, :, :] - table[..., :-1, :, :]
    position = x * knots - 0.5
    for knot in range(knots - 1):
        out.addcmul_(torch.sub(position, knot).clamp_(0.0, 1.0), steps[..., knot, :, :])
    return out


def add_noise_(
    x: Tensor,
    std: Tensor,
    field: Tensor,
    row_sigma: Tensor | None = None,
    row_normal: Tensor | None = None,
    column_sigma: Tensor | None = None,
    column_normal: Tensor | None = None,
) -> Tensor:
    """In place: ``x + std · field + row_sigma · row_normal + column_sigma · column_normal``, clamped to [0, 1].

    ``row_normal`` is ``[..., 3, H, 1]`` and ``column_normal`` ``[..., 3, 1, W]``; a pair left ``None`` adds nothing.
    """
    x.addcmul_(std, field)
    if row_normal is not None and row_sigma is not None:
        x.add_(row_normal * row_sigma)
    if column_normal is not None and column_sigma is not None:
        x.add_(column_normal * column_sigma)
    return x.clamp_(0.0, 1.0)
