"""The training critic of the two-sample fit: a small spectrally normalised patch critic that sees the image's high
frequencies only, and the frequency split it shares with the content term.

The split is a Gaussian low-pass: what it keeps is the clean image's (the content term holds the learned stage to
it), what it removes is the texture the critic compares with the camera's (Fritsche et al. 2019). Spectral norm on
every layer bounds the critic's gain, which keeps a hinge-loss game stable with small batches (Miyato et al. 2018).

References:
    M. Fritsche, S. Gu, R. Timofte, "Frequency Separation for Real-World Super-Resolution", ICCV Workshops 2019.
    T. Miyato, T. Kataoka, M. Koyama, Y. Yoshida, "Spectral Normalization for Generative Adversarial Networks",
    ICLR 2018.
    P. Isola, J.-Y. Zhu, T. Zhou, A. A. Efros, "Image-to-Image Translation with Conditional Adversarial Networks"
    (PatchGAN), CVPR 2017.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn
from torch.nn.utils.parametrizations import spectral_norm

from camdegrade.functional.optics.blur import blur_image

__all__ = ["PatchCritic", "high_pass", "low_pass"]

#: Slope of the critic's leaky ReLUs.
SLOPE = 0.2


def low_pass(image: Tensor, sigma: float) -> Tensor:
    """The Gaussian low-pass of ``image`` ``(N, 3, H, W)`` (sRGB values, differentiable)."""
    return blur_image(image, sigma)


def high_pass(image: Tensor, sigma: float) -> Tensor:
    """``image`` minus its :func:`low_pass`: the texture the critic compares."""
    return image - low_pass(image, sigma)


class PatchCritic(nn.Module):
    """High-pass patches ``(N, 3, P, P)`` → a map of logits ``(N, 1, P/4, P/4)`` (above 0: the camera's), each
    from a window of 26² pixels. The input is divided by :attr:`scale` (set from the captures'
    high-pass std with :meth:`standardise`) so that spectral norm's unit gain leaves logits of order one."""

    scale: Tensor

    def __init__(self, width: int = 16, *, high_only: bool = True) -> None:
        super().__init__()
        self.register_buffer("scale", torch.ones(()))
        self.high_only = high_only
        wide = 2 * width
        self.layers = nn.Sequential(
            spectral_norm(nn.Conv2d(3, width, 4, stride=2, padding=1)),
            nn.LeakyReLU(SLOPE),
            spectral_norm(nn.Conv2d(width, wide, 4, stride=2, padding=1)),
            nn.LeakyReLU(SLOPE),
            spectral_norm(nn.Conv2d(wide, wide, 3, padding=1)),
            nn.LeakyReLU(SLOPE),
            spectral_norm(nn.Conv2d(wide, 1, 3, padding=1)),
        )

    def planes(self, image: Tensor, sigma: float) -> Tensor:
        """What the critic sees of ``image``: its high-pass (or the whole image less ½, without ``high_only``)."""
        return high_pass(image, sigma) if self.high_only else image - 0.5

    def standardise(self, real: Tensor, sigma: float) -> None:
        """Set :attr:`scale` from a batch of the camera's patches."""
        self.scale.fill_(float(self.planes(real, sigma).std().clamp_min(1e-4)))

    def forward(self, planes: Tensor) -> Tensor:
        return self.layers(planes / self.scale)
