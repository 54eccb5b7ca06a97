"""AKLD: how far simulated noise is from a camera's real noise, pixel by pixel, as the noise-modelling papers score it.

At every pixel and channel the noise of a noisy image around its clean image is read as a zero-mean Gaussian whose
variance is the local mean of the squared difference (a 7×7 Gaussian window); the simulation's Gaussian is compared
with the real capture's at the same pixel by the Kullback–Leibler divergence, averaged over the pixels and channels
of each image, then over the images. 0: the same local noise level everywhere; two independent draws of the very
same noise score a little above 0 (each local variance rests on about 25 pixels).

References:
    Z. Yue, Q. Zhao, L. Zhang, D. Meng, "Dual Adversarial Network: Toward Real-world Noise Removal and Noise
    Generation" (DANet), ECCV 2020 (the measure and its window).
    Y. Cai, X. Hu, H. Wang, Y. Zhang, H. Pfister, D. Wei, "Learning to Generate Realistic Noisy Images via
    Pixel-level Noise-aware Adversarial Training" (PNGAN), NeurIPS 2021 (AKLD 0.153 on SIDD sRGB).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor

from camdegrade._support.pixels import as_unit

__all__ = ["MIN_VARIANCE", "RATIO_RANGE", "WINDOW", "Images", "akld", "gaussian_window", "local_noise_variance"]

#: Side of the Gaussian window of the local variance; its sigma is OpenCV's default for that side
#: (``0.3 · ((side − 1) / 2 − 1) + 0.8`` = 1.4), as in DANet's evaluation.
WINDOW = 7
#: The variance ratio is clamped to this range before the divergence (DANet's), so that a pixel where one image has
#: no noise at all does not dominate the mean.
RATIO_RANGE = (0.1, 10.0)
#: Floor of a local variance (units of [0, 1] images squared).
MIN_VARIANCE = 1e-10

Images = Tensor | Sequence[Tensor]


def gaussian_window(side: int = WINDOW) -> Tensor:
    """``(side, side)`` normalised Gaussian weights with OpenCV's default sigma for that side."""
    if isinstance(side, bool) or not isinstance(side, int) or side < 3 or side % 2 == 0:
        raise ValueError(f"side must be an odd integer >= 3, got side={side!r}")
    sigma = 0.3 * ((side - 1) / 2 - 1) + 0.8
    offsets = torch.arange(side, dtype=torch.float64) - (side - 1) / 2
    line = torch.exp(-(offsets**2) / (2 * sigma**2))
    line = line / line.sum()
    return torch.outer(line, line)


def local_noise_variance(noisy: Tensor, clean: Tensor, side: int = WINDOW) -> Tensor:
    """``(N, 3, H, W)`` (float64): the local mean of ``(noisy − clean)²`` under :func:`gaussian_window` (borders
    reflected), at least :data:`MIN_VARIANCE`. Both images ``(N, 3, H, W)`` or ``(3, H, W)``, [0, 1] or uint8."""
    noisy, clean = _batched(noisy, "noisy"), _batched(clean, "clean")
    _check_same_shape(noisy, "noisy", clean, "clean")
    pad = side // 2
    if min(noisy.shape[-2:]) <= pad:
        raise ValueError(
            f"images must be larger than {pad} pixels on each side for a {side}×{side} window, "
            f"got {tuple(noisy.shape[-2:])}"
        )
    squared = (noisy.double() - clean.double()) ** 2
    kernel = gaussian_window(side).to(squared.device).expand(squared.shape[1], 1, side, side)
    padded = F.pad(squared, (pad, pad, pad, pad), mode="reflect")
    return F.conv2d(padded, kernel, groups=squared.shape[1]).clamp_min(MIN_VARIANCE)


def akld(simulated: Images, real: Images, clean: Images, *, side: int = WINDOW) -> float:
    """The average KL divergence ``KL(N(0, σ²_sim) ‖ N(0, σ²_real))`` of the local noise of ``simulated`` and
    ``real``, both around ``clean``: per image the mean over pixels and channels, then the mean over images.

    With ``v = σ²_sim / σ²_real`` clamped to :data:`RATIO_RANGE` the divergence at a pixel is
    ``(v − 1 − ln v) / 2``: 0 where the levels agree, ``(k² − 1 − 2 ln k) / 2`` where the simulated noise is ``k``
    times the real one.

    Args:
        simulated, real, clean: one image each (``(3, H, W)`` or ``(N, 3, H, W)``) or sequences of as many images
            (any sizes, each the same size as its partners), float in [0, 1] or uint8.
        side: window side (odd; DANet's 7).

    Returns:
        The AKLD (PNGAN reports 0.153 on SIDD sRGB; DANet 0.212).

    References:
        Z. Yue et al., "Dual Adversarial Network: Toward Real-world Noise Removal and Noise Generation", ECCV 2020.
        Y. Cai et al., "Learning to Generate Realistic Noisy Images via Pixel-level Noise-aware Adversarial
        Training", NeurIPS 2021.
    """
    frames = _frames(simulated, "simulated"), _frames(real, "real"), _frames(clean, "clean")
    if not len(frames[0]) == len(frames[1]) == len(frames[2]):
        raise ValueError(
            "simulated, real and clean must hold as many images each, got "
            f"{len(frames[0])}, {len(frames[1])} and {len(frames[2])}"
        )
    low, high = RATIO_RANGE
    scores = []
    for sim, capture, reference in zip(*frames, strict=True):
        _check_same_shape(sim, "simulated", capture, "real")
        ratio = local_noise_variance(sim, reference, side) / local_noise_variance(capture, reference, side)
        ratio = ratio.clamp(low, high)
        scores.extend((0.5 * (ratio - 1 - torch.log(ratio))).mean((1, 2, 3)).tolist())
    return math.fsum(scores) / len(scores)


def _frames(images: Images, name: str) -> list[Tensor]:
    """``images`` as a list of ``(N, 3, H, W)`` float tensors."""
    if isinstance(images, Tensor):
        return [_batched(images, name)]
    if not isinstance(images, Sequence) or isinstance(images, (str, bytes)):
        raise TypeError(f"{name} must be a tensor or a sequence of tensors, got {type(images).__name__}")
    if not images:
        raise ValueError(f"{name} must hold at least one image, got an empty sequence")
    return [_batched(image, f"{name}[{index}]") for index, image in enumerate(images)]


def _batched(image: Tensor, name: str) -> Tensor:
    if not isinstance(image, Tensor):
        raise TypeError(f"{name} must be a tensor, got {type(image).__name__}")
    if image.dtype != torch.uint8 and not image.is_floating_point():
        raise TypeError(f"{name} must be a float image in [0, 1] or uint8, got dtype {image.dtype}")
    if image.dim() not in (3, 4) or image.shape[-3] != 3:
        raise ValueError(f"{name} must be an image [N, 3, H, W] or [3, H, W], got shape {tuple(image.shape)}")
    unit = as_unit(image)
    return unit if unit.dim() == 4 else unit[None]


def _check_same_shape(first: Tensor, first_name: str, second: Tensor, second_name: str) -> None:
    if first.shape != second.shape:
        raise ValueError(
            f"{first_name} and {second_name} must have the same shape, got {tuple(first.shape)} and "
            f"{tuple(second.shape)}"
        )
