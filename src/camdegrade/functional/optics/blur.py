"""Blur kernels: a point-spread function (anisotropic Gaussian ⊛ linear motion) and per-sample convolution."""

from __future__ import annotations

import functools
import math

import torch
import torch.nn.functional as F
from torch import Tensor

from camdegrade.functional._utils import ParamLike, apply_float, check_image, flat_param, one_plane_at_a_time
from camdegrade.functional.isp.color import linear_to_srgb, linear_to_srgb_, srgb_to_linear

__all__ = [
    "FFT_RADIUS",
    "MOTION_SAMPLES",
    "NEGLIGIBLE_TAP",
    "TRUNCATE",
    "blur_image",
    "blur_planes",
    "convolve_image",
    "convolve_separable",
    "psf_kernel",
    "separable_taps",
]

#: Gaussian support in standard deviations; the mass left out is below 1e-4, far under one 8-bit level.
TRUNCATE = 4.0
#: Separable blurs leave out outer taps lighter than this (each direction's taps sum to 1). For images in [0, 1]
#: the result moves by less than 1e-4 (a few such taps per pass, two passes), 0.03 of an 8-bit level.
NEGLIGIBLE_TAP = 1e-5
#: Points sampled along a motion path (bilinearly splatted, so lengths up to this many pixels stay gap-free).
MOTION_SAMPLES = 128
_MIN_SIGMA = 1e-3
#: Kernels of at least this radius (and all float64 convolutions, which have no fast direct path on the CPU)
#: are applied through the FFT; both paths give the same result to rounding.
FFT_RADIUS = 12


def psf_kernel(
    sigma_x: Tensor,
    sigma_y: Tensor | None = None,
    angle: Tensor | None = None,
    motion_length: Tensor | None = None,
    motion_angle: Tensor | None = None,
) -> Tensor:
    """Per-sample normalised PSFs ``(M, K, K)`` from per-sample ``(M,)`` parameters (differentiable).

    The Gaussian has standard deviations ``sigma_x``/``sigma_y`` (pixels) along axes rotated by ``angle``
    degrees and is truncated at ``TRUNCATE`` of its own largest sigma, so a sample's kernel does not depend on
    the rest of the batch. It is convolved with a line segment of ``motion_length`` pixels at
    ``motion_angle`` degrees.
    Zero sigmas and zero length give a unit impulse (the identity).
    """
    sigma_x = sigma_x.clamp_min(0.0)
    sigma_y = sigma_x if sigma_y is None else sigma_y.clamp_min(0.0)
    zeros = torch.zeros_like(sigma_x)
    angle = zeros if angle is None else angle
    gaussian = _gaussian_kernel(sigma_x, sigma_y, angle)
    if motion_length is None or not bool((motion_length > 0).any()):
        return gaussian
    motion = _motion_kernel(motion_length.clamp_min(0.0), zeros if motion_angle is None else motion_angle)
    radius = gaussian.shape[-1] // 2
    combined = F.conv2d(
        motion.unsqueeze(0), gaussian.flip(-1, -2).unsqueeze(1), padding=2 * radius, groups=gaussian.shape[0]
    )[0]
    return combined / combined.sum(dim=(-1, -2), keepdim=True)


def _gaussian_kernel(sigma_x: Tensor, sigma_y: Tensor, angle: Tensor) -> Tensor:
    largest = torch.maximum(sigma_x, sigma_y).detach()
    own_radius = torch.ceil(TRUNCATE * largest).where(largest > 0.05, torch.zeros_like(largest))
    radius = int(own_radius.max().item()) if own_radius.numel() else 0
    coords = torch.arange(-radius, radius + 1, dtype=sigma_x.dtype, device=sigma_x.device)
    y, x = torch.meshgrid(coords, coords, indexing="ij")
    theta = torch.deg2rad(angle)[:, None, None]
    u = x * torch.cos(theta) + y * torch.sin(theta)
    v = -x * torch.sin(theta) + y * torch.cos(theta)
    sx = sigma_x.clamp_min(_MIN_SIGMA)[:, None, None]
    sy = sigma_y.clamp_min(_MIN_SIGMA)[:, None, None]
    weights = torch.exp(-0.5 * ((u / sx) ** 2 + (v / sy) ** 2))
    inside = (x.abs() <= own_radius[:, None, None]) & (y.abs() <= own_radius[:, None, None])
    weights = weights * inside
    return weights / weights.sum(dim=(-1, -2), keepdim=True)


def _motion_kernel(length: Tensor, angle: Tensor) -> Tensor:
    radius = math.ceil(float(length.detach().max()) / 2.0) + 1
    coords = torch.arange(-radius, radius + 1, dtype=length.dtype, device=length.device)
    steps = torch.linspace(-0.5, 0.5, MOTION_SAMPLES, dtype=length.dtype, device=length.device)
    theta = torch.deg2rad(angle)[:, None]
    along = length[:, None] * steps  # (M, S)
    px, py = along * torch.cos(theta), along * torch.sin(theta)
    # Bilinear splat of every path point onto the pixel grid (a tent in x times a tent in y).
    wx = (1.0 - (coords - px[..., None]).abs()).clamp_min(0.0)  # (M, S, K)
    wy = (1.0 - (coords - py[..., None]).abs()).clamp_min(0.0)
    return torch.einsum("msy,msx->myx", wy, wx) / MOTION_SAMPLES


def convolve_image(image: Tensor, kernel: ParamLike) -> Tensor:
    """Convolve each channel with a kernel ``(K, K)`` or per-sample ``(N, K, K)``, K odd, reflect-padded."""
    check_image(image)
    weights = torch.as_tensor(kernel)
    if weights.ndim < 2 or weights.shape[-1] != weights.shape[-2] or weights.shape[-1] % 2 == 0:
        raise ValueError(f"kernel must have shape (K, K) or (N, K, K) with K odd, got shape {tuple(weights.shape)}")
    size = weights.shape[-1]
    flat = flat_param(weights, image, "kernel", (size, size))
    return apply_float(image, lambda x: _convolve(x, flat))


def _convolve(x: Tensor, kernels: Tensor) -> Tensor:
    radius = kernels.shape[-1] // 2
    if x.numel() == 0:
        return x.clone()
    if radius == 0:
        return x * kernels.reshape(*x.shape[:-3], 1, 1, 1)
    height, width = x.shape[-2:]
    planes = x.reshape(-1, 3, height, width)
    mode = "reflect" if radius < min(height, width) else "replicate"
    padded = F.pad(planes, (radius, radius, radius, radius), mode=mode)
    weights = kernels.to(x.dtype)
    use_fft = radius >= FFT_RADIUS or x.dtype == torch.float64
    out = _convolve_fft(padded, weights) if use_fft else _convolve_direct(padded, weights)
    return out.reshape(x.shape)


def _convolve_direct(padded: Tensor, kernels: Tensor) -> Tensor:
    batch, channels, height, width = padded.shape
    weight = kernels.flip(-1, -2).repeat_interleave(channels, dim=0).unsqueeze(1)
    out = F.conv2d(padded.reshape(1, batch * channels, height, width), weight, groups=batch * channels)
    return out.reshape(batch, channels, *out.shape[-2:])


def _convolve_fft(padded: Tensor, kernels: Tensor) -> Tensor:
    """The 'valid' part of the convolution, via the FFT (large kernels; same result as the direct path), one image at
    a time on a CPU (:func:`~camdegrade.functional._utils.one_plane_at_a_time`)."""
    shape = padded.shape[-2:]
    size = kernels.shape[-1]
    kernels = kernels.expand(len(padded), -1, -1) if len(kernels) == 1 else kernels

    def convolved(planes: Tensor, kernel: Tensor) -> Tensor:
        spectra = torch.fft.rfft2(planes, s=shape) * torch.fft.rfft2(kernel, s=shape)[:, None]
        return torch.fft.irfft2(spectra, s=shape)

    return one_plane_at_a_time(convolved, padded, kernels)[..., size - 1 :, size - 1 :]


def blur_image(
    image: Tensor,
    sigma: ParamLike,
    sigma_y: ParamLike | None = None,
    angle: ParamLike = 0.0,
    motion_length: ParamLike = 0.0,
    motion_angle: ParamLike = 0.0,
    *,
    linear: bool = False,
) -> Tensor:
    """Blur with a point-spread function: a Gaussian of ``sigma`` pixels (anisotropic with ``sigma_y``, axes
    rotated by ``angle`` degrees), optionally convolved with linear motion of ``motion_length`` pixels at
    ``motion_angle`` degrees.

    Every parameter is a scalar or per-sample ``(N,)``; ``sigma = 0``, ``motion_length = 0`` is the identity.
    ``linear=True`` blurs linear light (as a lens does) and re-encodes the result as sRGB.

    Examples:
        >>> image = torch.rand(2, 3, 32, 32, generator=torch.Generator().manual_seed(0))
        >>> blur_image(image, torch.tensor([0.0, 1.5])).shape
        torch.Size([2, 3, 32, 32])
    """
    check_image(image)
    sx = flat_param(sigma, image, "sigma")
    sy = sx if sigma_y is None else flat_param(sigma_y, image, "sigma_y")
    length = flat_param(motion_length, image, "motion_length")
    for name, value in (("sigma", sx), ("sigma_y", sy), ("motion_length", length)):
        if bool((value < 0).any()):
            raise ValueError(f"{name} must be non-negative, got {name}={value[value < 0][0].item():g}")
    angles = flat_param(angle, image, "angle")
    motion_angles = flat_param(motion_angle, image, "motion_angle")
    needs_graph = torch.is_grad_enabled() and any(t.requires_grad for t in (image, sx, sy, angles, length))
    taps = None if needs_graph else separable_taps(sx, sy, angles, length)
    if taps is None:
        kernels = psf_kernel(sx, sy, angles, length, motion_angles)
        convolve = lambda x: _convolve(x, kernels.to(x.dtype))  # noqa: E731
    else:
        convolve = lambda x: convolve_separable(x, taps[0].to(x.dtype), taps[1].to(x.dtype))  # noqa: E731

    def kernel(x: Tensor) -> Tensor:
        if not linear:
            return convolve(x)
        blurred = convolve(srgb_to_linear(x))
        return linear_to_srgb(blurred) if needs_graph else linear_to_srgb_(blurred)

    return apply_float(image, kernel)


def blur_planes(planes: Tensor, sigma: ParamLike) -> Tensor:
    """Each of the float ``(P, H, W)`` planes (a luma, say) blurred alone by the Gaussian of :func:`blur_image`:
    they go three at a time as the channels of an image, so a single plane costs one plane's work, not three."""
    count, size = planes.shape[-3], planes.shape[-2:]
    padded = F.pad(planes, (0, 0, 0, 0, 0, -count % 3))
    return blur_image(padded.reshape(-1, 3, *size), sigma).reshape(-1, *size)[:count]


def separable_taps(
    sigma_x: Tensor, sigma_y: Tensor, angle: Tensor, motion_length: Tensor
) -> tuple[Tensor, Tensor] | None:
    """1-D taps ``(M, K)`` along x and along y whose outer product is :func:`psf_kernel` for per-sample ``(M,)``
    parameters, when every sample's PSF is a Gaussian that factorises (no motion; isotropic or aligned with the
    axes); else None. Use them with :func:`convolve_separable`."""
    sigmas = _separable_sigmas(sigma_x, sigma_y, angle, motion_length)
    return None if sigmas is None else _gaussian_taps(*sigmas)


@functools.lru_cache(maxsize=64)
def gaussian_taps(sigma: float) -> tuple[float, ...]:
    """The 1-D taps of :func:`blur_image`'s isotropic Gaussian of ``sigma`` pixels (computed in float32, as a
    float32 ``sigma`` buffer gives them, negligible outer taps trimmed), as Python floats; cached."""
    value = torch.tensor([sigma], dtype=torch.float32)
    zero = torch.zeros_like(value)
    across, _ = _gaussian_taps(*_separable_sigmas(value, value, zero, zero))  # type: ignore[misc]
    return tuple(float(tap) for tap in across[0])


def _separable_sigmas(sigma_x: Tensor, sigma_y: Tensor, angle: Tensor, length: Tensor) -> tuple[Tensor, Tensor] | None:
    """The Gaussian's sigmas along the image's x and y axes when every sample's PSF is one (no motion, and
    isotropic or aligned with the axes), else None."""
    if bool((length > 0).any()):
        return None
    quarter_turns = angle / 90.0
    aligned = (quarter_turns == quarter_turns.round()) | (sigma_x == sigma_y)
    if not bool(aligned.all()):
        return None
    swapped = (quarter_turns.round().remainder(2) == 1) & (sigma_x != sigma_y)
    return torch.where(swapped, sigma_y, sigma_x), torch.where(swapped, sigma_x, sigma_y)


def _gaussian_taps(sigma_x: Tensor, sigma_y: Tensor) -> tuple[Tensor, Tensor]:
    """Per-sample 1-D taps ``(M, K)`` along x and along y whose outer product is :func:`psf_kernel`'s axis-aligned
    Gaussian (same square support of ``TRUNCATE`` times the larger sigma, each factor normalised)."""
    largest = torch.maximum(sigma_x, sigma_y).clamp_min(0.0)
    own_radius = torch.ceil(TRUNCATE * largest).where(largest > 0.05, torch.zeros_like(largest))
    radius = int(own_radius.max().item()) if own_radius.numel() else 0
    coords = torch.arange(-radius, radius + 1, dtype=sigma_x.dtype, device=sigma_x.device)
    inside = coords.abs() <= own_radius[:, None]

    def taps(sigma: Tensor) -> Tensor:
        weights = torch.exp(-0.5 * (coords / sigma.clamp_min(_MIN_SIGMA)[:, None]) ** 2) * inside
        return weights / weights.sum(dim=-1, keepdim=True)

    return _trim_negligible(taps(sigma_x), taps(sigma_y))


def _trim_negligible(across: Tensor, down: Tensor) -> tuple[Tensor, Tensor]:
    """Both tap sets without the outer pairs that weigh less than :data:`NEGLIGIBLE_TAP` in every sample and
    direction, renormalised: each dropped pair costs a pass over the image and changes no 8-bit output."""
    if across.shape[-1] < 3:
        return across, down
    outer = torch.maximum(across, down).amax(dim=0)
    needed = torch.maximum(outer, outer.flip(0)) >= NEGLIGIBLE_TAP
    cut = min(int(needed.int().argmax()), across.shape[-1] // 2)
    if cut == 0:
        return across, down
    kept = slice(cut, across.shape[-1] - cut)
    return tuple(t[:, kept] / t[:, kept].sum(dim=-1, keepdim=True) for t in (across, down))  # type: ignore[return-value]


def convolve_separable(x: Tensor, across: Tensor, down: Tensor) -> Tensor:
    """Reflect-padded convolution of float ``x`` ``[..., 3, H, W]`` with separable kernels: taps ``(1, K)``
    shared by every sample or ``(M, K)`` per sample, along x (``across``) then y (``down``).

    Computed as sums of shifted planes: on the CPU this is several times faster than a depthwise ``conv2d`` for
    the small kernels cameras need."""
    radius = across.shape[-1] // 2
    if x.numel() == 0 or radius == 0:
        return x.clone()
    height, width = x.shape[-2:]
    planes = x.reshape(-1, 3, height, width)
    mode = "reflect" if radius < min(height, width) else "replicate"
    padded = F.pad(planes, (radius, radius, radius, radius), mode=mode)
    rows = _shifted_sum(padded, across, dim=-1, size=width)
    return _shifted_sum(rows, down, dim=-2, size=height).reshape(x.shape)


def _shifted_sum(planes: Tensor, taps: Tensor, dim: int, size: int) -> Tensor:
    """``Σ_i taps[:, i] · planes.narrow(dim, i, size)`` with one weight per sample (leading dim of ``planes``)."""
    weights: list[float] | Tensor = taps[0].tolist() if taps.shape[0] == 1 else taps[:, :, None, None, None]
    # One shared kernel: Python floats, so each step is a single fused multiply-add with no broadcasting.
    total = None
    for index in range(taps.shape[-1]):
        shifted = planes.narrow(dim, index, size)
        weight = weights[index] if isinstance(weights, list) else weights[:, index]
        if total is None:
            total = shifted * weight
        elif isinstance(weight, float):
            total.add_(shifted, alpha=weight)
        else:
            total.addcmul_(shifted, weight)
    assert total is not None
    return total
