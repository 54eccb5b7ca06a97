"""The denoiser of the PSNR-gap bench (``bench_noise_gap.py``): the small residual CNN of ``residual_cnn.py``
trained on random windows of (clean, noisy) training images and scored on full held-out real captures."""

from __future__ import annotations

import statistics
from collections.abc import Sequence
from dataclasses import dataclass

import torch
from residual_cnn import ResidualCNN, apply_network, make_network, psnr_db, train_network
from torch import Tensor, nn

__all__ = ["Denoiser", "denoise", "make_denoiser", "psnr_db", "test_psnr", "train_denoiser"]


@dataclass(frozen=True)
class Denoiser(ResidualCNN):
    """:class:`ResidualCNN` with the noise bench's settings (its defaults): 400 steps of 16 windows of 48²."""


make_denoiser = make_network
denoise = apply_network


def train_denoiser(cleans: Sequence[Tensor], noisies: Sequence[Tensor], config: Denoiser, seed: int) -> nn.Module:
    """A denoiser trained on windows of ``(noisy, clean)`` float ``(3, H, W)`` images in [0, 1]."""
    return train_network(cleans, noisies, config, seed)


def test_psnr(model: nn.Module, pairs: Sequence[tuple[Tensor, Tensor]], fold: int) -> float:
    """Mean PSNR (dB) of the denoised held-out real captures against their clean images, ``(clean, capture)``."""
    with torch.no_grad():
        return statistics.fmean(psnr_db(denoise(model, x[None], fold)[0].clamp(0, 1), c) for c, x in pairs)
