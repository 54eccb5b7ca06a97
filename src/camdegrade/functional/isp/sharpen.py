"""Detail kernels of a camera's ISP on its sRGB output: unsharp masking with soft coring (sharpening), and coring
alone (noise reduction: the faint detail removed, the strong detail kept).

References:
    W. F. Schreiber, "Wirephoto quality improvement by unsharp masking", Pattern Recognition 2(2), 1970 (unsharp
    masking); J. P. Rossi, "Digital techniques for reducing television noise", SMPTE Journal 87(3), 1978 (coring).
"""

from __future__ import annotations

import torch
from torch import Tensor

from camdegrade.functional._utils import (
    ParamLike,
    apply_float,
    as_channel_view,
    check_image,
    per_sample,
    restore,
    to_float,
)
from camdegrade.functional.analysis.images import luma as luma_of
from camdegrade.functional.filtering import convolve_terms, luma_plane
from camdegrade.functional.optics.blur import blur_image, gaussian_taps

__all__ = ["coring", "denoise_image", "faint_part", "unsharp_mask_image"]


def coring(detail: Tensor, threshold: Tensor) -> Tensor:
    """``detail · d² / (d² + threshold²)``: detail well above ``threshold`` passes, detail well below it is zeroed,
    half of it passes at the threshold. Smooth in both arguments (a fitter differentiates it); a zero threshold
    passes everything."""
    square = detail * detail
    return detail * square / (square + threshold * threshold).clamp_min(torch.finfo(detail.dtype).tiny)


def unsharp_mask_image(
    image: Tensor, sigma: ParamLike, amount: ParamLike, threshold: ParamLike = 0.0, *, luma: bool = True
) -> Tensor:
    """Sharpen: ``clip(x + amount · coring(x − G_σ ⊛ x, threshold), 0, 1)`` on the sRGB values ``x``.

    Args:
        image: ``[..., 3, H, W]`` uint8 or float in [0, 1] (sRGB-encoded: an ISP sharpens encoded values).
        sigma: the Gaussian's standard deviation in pixels (the radius of the halo); 0 leaves nothing to sharpen.
        amount: the gain of the detail ``x − G_σ ⊛ x``; 0 is the identity, negative values soften.
        threshold: the detail amplitude (in [0, 1] units) at which :func:`coring` passes half of it, so that
            noise and fine grain below it are not amplified. 0 passes all detail.
        luma: take the detail of the Rec. 601 luma and add it to R, G and B alike (no colour fringes), rather
            than per channel.

    Every parameter is a scalar or per-sample ``(N,)``.

    Examples:
        >>> image = torch.rand(2, 3, 32, 32, generator=torch.Generator().manual_seed(0))
        >>> unsharp_mask_image(image, 1.0, torch.tensor([0.0, 1.5]), 0.01).shape
        torch.Size([2, 3, 32, 32])
    """
    check_image(image)
    amount_t = as_channel_view(per_sample(amount, image, "amount"))
    threshold_t = _checked_threshold(threshold, image)
    cored = threshold_t.requires_grad or bool((threshold_t > 0).any())

    def kernel(x: Tensor) -> Tensor:
        detail = _detail(x, sigma, luma)
        if cored:
            detail = coring(detail, threshold_t.to(x.dtype))
        return (x + amount_t.to(x.dtype) * detail).clamp(0.0, 1.0)

    return apply_float(image, kernel)


def denoise_image(image: Tensor, sigma: ParamLike, threshold: ParamLike, *, luma: bool = True) -> Tensor:
    """Noise reduction by coring: ``clip(x − (d − coring(d, threshold)), 0, 1)`` with ``d = x − G_σ ⊛ x``: detail well
    below ``threshold`` is smoothed away (the output is ``G_σ ⊛ x`` there), detail well above it is kept, so edges
    stay sharp while faint grain and fine texture vanish — the "painted" look of a phone's processed output.

    Args:
        image: ``[..., 3, H, W]`` uint8 or float in [0, 1] (sRGB-encoded).
        sigma: the Gaussian's standard deviation in pixels (the scale of the detail removed).
        threshold: the detail amplitude (in [0, 1] units) at which half of it is removed; 0 is the identity.
        luma: core the Rec. 601 luma detail and take it off R, G and B alike (the chroma detail is kept), rather
            than each channel.

    Every parameter is a scalar or per-sample ``(N,)``.

    Examples:
        >>> image = torch.rand(2, 3, 32, 32, generator=torch.Generator().manual_seed(0))
        >>> bool((denoise_image(image, 1.0, 0.0) == image).all())
        True
    """
    check_image(image)
    threshold_t = _checked_threshold(threshold, image)
    if not threshold_t.requires_grad and not bool((threshold_t > 0).any()):
        return image.clone()

    def kernel(x: Tensor) -> Tensor:
        return (x - faint_part(_detail(x, sigma, luma), threshold_t.to(x.dtype))).clamp(0.0, 1.0)

    return apply_float(image, kernel)


def image_detail(image: Tensor, sigma: ParamLike, *, luma: bool = True) -> Tensor:
    """The detail :func:`denoise_image` cores, ``x − G_σ ⊛ x`` of float ``image`` ``[..., 3, H, W]`` (of its luma,
    ``[..., 1, H, W]``, with ``luma``), for :func:`denoised_with_detail`: a fit trying many thresholds at one sigma
    takes it once."""
    check_image(image)
    return _detail(to_float(image), sigma, luma)


def denoised_with_detail(image: Tensor, detail: Tensor, threshold: ParamLike) -> Tensor:
    """:func:`denoise_image` of ``image`` given its :func:`image_detail` at the sigma wanted: the same values."""
    check_image(image)
    x = to_float(image)
    threshold_t = _checked_threshold(threshold, image)
    return restore((x - faint_part(detail, threshold_t.to(x.dtype))).clamp(0.0, 1.0), image)


def faint_part(detail: Tensor, threshold: Tensor) -> Tensor:
    """The part of ``detail`` that :func:`coring` removes: ``detail · t² / (d² + t²)`` (all of it well below the
    threshold, none well above it)."""
    return detail - coring(detail, threshold)


def luma_detail(image: Tensor, sigma: float) -> Tensor:
    """``Y − G_σ ⊛ Y``, ``(N, 1, H, W)``, of the Rec. 601 luma ``Y`` of float ``image`` ``(N, 3, H, W)`` (no autograd;
    the border mirrored, sigma's radius below H and W): the detail :func:`unsharp_mask_image` and
    :func:`denoise_image` take with ``luma``, its luma taken first, so that one plane is blurred instead of three
    (the same Gaussian taps; equal up to float rounding)."""
    taps = gaussian_taps(sigma)
    return convolve_terms(luma_plane(image), 1.0, [(-1.0, taps, taps)])


def cored_(detail: Tensor, threshold: float) -> Tensor:
    """:func:`coring` of ``detail`` with a positive ``threshold``, in place: ``d³ / (d² + t²)``."""
    square = detail * detail
    return detail.mul_(square).div_(square.add_(threshold * threshold))


def faint_part_(detail: Tensor, threshold: float) -> Tensor:
    """:func:`faint_part` of ``detail`` with a positive ``threshold``, in place: ``d · t² / (d² + t²)``."""
    square = (detail * detail).add_(threshold * threshold)
    return detail.mul_(threshold * threshold).div_(square)


def _checked_threshold(threshold: ParamLike, image: Tensor) -> Tensor:
    """``threshold`` per sample, viewed against the channels of ``image``; a negative one is refused."""
    threshold_t = as_channel_view(per_sample(threshold, image, "threshold"))
    if bool((threshold_t < 0).any()):
        raise ValueError(f"threshold must be non-negative, got threshold={threshold_t[threshold_t < 0][0].item():g}")
    return threshold_t


def _detail(x: Tensor, sigma: ParamLike, luma: bool) -> Tensor:
    """``x − G_σ ⊛ x``: of the Rec. 601 luma, ``[..., 1, H, W]`` (to add to R, G and B alike), or per channel."""
    detail = x - blur_image(x, sigma)
    return luma_of(detail).unsqueeze(-3) if luma else detail
