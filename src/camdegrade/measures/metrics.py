"""Full-reference image quality metrics used to report how close a degradation is to real captures."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from camdegrade._support.pixels import as_unit

__all__ = ["psnr", "ssim"]


def psnr(prediction: Tensor, target: Tensor) -> float:
    """Peak signal-to-noise ratio in dB over all pixels, for uint8 or [0, 1] float images of equal shape."""
    if prediction.shape != target.shape:
        raise ValueError(
            f"prediction and target must have the same shape, got {tuple(prediction.shape)} and {tuple(target.shape)}"
        )
    mse = torch.mean((as_unit(prediction) - as_unit(target)) ** 2).item()
    return float("inf") if mse == 0 else -10.0 * torch.log10(torch.tensor(mse)).item()


def ssim(prediction: Tensor, target: Tensor, window_sigma: float = 1.5) -> float:
    """Mean structural similarity (Gaussian window σ=1.5, 11×11, constants of Wang et al. 2004), averaged over
    channels, for ``[..., 3, H, W]`` uint8 or [0, 1] float images."""
    if prediction.shape != target.shape:
        raise ValueError(
            f"prediction and target must have the same shape, got {tuple(prediction.shape)} and {tuple(target.shape)}"
        )
    if min(prediction.shape[-2:]) < 11:
        raise ValueError(f"ssim needs images of at least 11×11 pixels, got {tuple(prediction.shape[-2:])}")
    x = as_unit(prediction).reshape(-1, 1, *prediction.shape[-2:])
    y = as_unit(target).reshape(-1, 1, *target.shape[-2:])
    radius = 5
    offsets = torch.arange(-radius, radius + 1, dtype=torch.float32)
    kernel_1d = torch.exp(-(offsets**2) / (2 * window_sigma**2))
    kernel_1d = kernel_1d / kernel_1d.sum()
    kernel = (kernel_1d[:, None] * kernel_1d[None, :])[None, None].to(x.device)

    def local_mean(image: Tensor) -> Tensor:
        return F.conv2d(image, kernel)

    mu_x, mu_y = local_mean(x), local_mean(y)
    var_x = local_mean(x * x) - mu_x**2
    var_y = local_mean(y * y) - mu_y**2
    cov = local_mean(x * y) - mu_x * mu_y
    c1, c2 = 0.01**2, 0.03**2
    ssim_map = ((2 * mu_x * mu_y + c1) * (2 * cov + c2)) / ((mu_x**2 + mu_y**2 + c1) * (var_x + var_y + c2))
    return float(ssim_map.mean())
