"""The restorer of the restoration-transfer bench (``bench_restoration_transfer.py``): the small residual CNN of
``residual_cnn.py`` with larger windows than the denoiser (a blur spreads over more pixels than noise does),
trained on (degraded, clean) windows of the training scenes and scored on whole held-out real captures with the
alignment-tolerant PSNR of ``aligned_scoring.py``."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
from aligned_scoring import align_tiles
from residual_cnn import ResidualCNN, apply_network
from restoration_evidence import added, band_sums
from torch import Tensor, nn


@dataclass(frozen=True)
class Restorer(ResidualCNN):
    """:class:`ResidualCNN` with the restoration bench's settings: windows of 80², 1500 steps."""

    steps: int = 1500
    patch: int = 80


def restore(model: nn.Module, capture: Tensor, fold: int) -> Tensor:
    """The restored float ``(3, H, W)`` image, clamped to [0, 1]."""
    with torch.no_grad():
        return apply_network(model, capture[None], fold)[0].clamp(0, 1)


def score(outputs: Sequence[Tensor], cleans: Sequence[Tensor]) -> tuple[list[float], dict[str, list[float]]]:
    """Each output's alignment-tolerant PSNR (dB) against its clean image, and the band sums of all of them
    (:func:`restoration_evidence.band_sums`)."""
    psnr, bands = [], []
    for output, clean in zip(outputs, cleans, strict=True):
        aligned = align_tiles(output, clean)
        psnr.append(aligned.psnr_db)
        bands.append(band_sums(aligned))
    return psnr, added(bands)
