"""Small test images for the effect and kernel tests: scikit-image's bundled photos and generated charts."""

from __future__ import annotations

from functools import cache

import skimage.data
import torch
import torch.nn.functional as F
from torch import Tensor


@cache
def _photo(name: str, long_side: int) -> Tensor:
    array = getattr(skimage.data, name)()
    image = torch.from_numpy(array).permute(2, 0, 1).float().div(255.0)
    scale = long_side / max(image.shape[-2:])
    return F.interpolate(image[None], scale_factor=scale, mode="area", recompute_scale_factor=False)[0]


def photo(name: str = "astronaut", long_side: int = 64) -> Tensor:
    """A scikit-image sample photo (``astronaut``, ``chelsea``, ``coffee``) area-resized, float ``(3, H, W)``."""
    return _photo(name, long_side).clone()


def photo_batch(height: int = 48, width: int = 64) -> Tensor:
    """Three different photos cropped to ``(3, 3, height, width)``."""
    crops = [
        photo(name, max(height, width) * 3 // 2)[:, :height, :width] for name in ("astronaut", "chelsea", "coffee")
    ]
    return torch.stack(crops)


def photos_for_fitting(long_side: int = 160) -> list[Tensor]:
    """Three photos of different sizes (fitters take lists of differently sized images)."""
    return [photo("astronaut", long_side), photo("coffee", long_side), photo("chelsea", long_side)]


def patch_chart(size: int = 192, patches: int = 8, seed: int = 0) -> Tensor:
    """Uniform colour patches spanning [0.02, 0.97]: flat areas at many intensities (for noise estimation)."""
    generator = torch.Generator().manual_seed(seed)
    levels = 0.02 + 0.95 * torch.rand(3, patches, patches, generator=generator)
    return F.interpolate(levels[None], size=(size, size), mode="nearest")[0]


def smooth_scenes(count: int, seed: int, side: int = 64) -> list[Tensor]:
    """Smooth random scenes (a coarse random field upsampled): flat enough for grain to show."""
    generator = torch.Generator().manual_seed(seed)
    coarse = torch.rand(count, 3, side // 16, side // 16, generator=generator) * 0.6 + 0.2
    return list(F.interpolate(coarse, size=(side, side), mode="bicubic").clamp(0, 1))


def grainy(images: list[Tensor], levels: float, seed: int) -> list[Tensor]:
    """``images`` with white Gaussian grain of ``levels`` 8-bit levels (seeded), clamped to [0, 1]."""
    generator = torch.Generator().manual_seed(seed)
    return [(image + levels / 255 * torch.randn(image.shape, generator=generator)).clamp(0, 1) for image in images]
