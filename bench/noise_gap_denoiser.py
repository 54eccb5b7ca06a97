"""The denoiser of the PSNR-gap bench (``bench_noise_gap.py``): a small residual CNN trained on random windows of
(clean, noisy) training images and scored on full held-out real captures. The same initialisation and the same
windows for every row of a seed, so that rows differ only in the noisy images they train on."""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass
from functools import partial
from itertools import pairwise

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from camdegrade._seeds import derived_generator


@dataclass(frozen=True)
class Denoiser:
    """The denoiser and its training: the image folded into ``fold``² planes of lower resolution (pixel unshuffle,
    as FFDNet does: a wider view for the same arithmetic), ``layers`` 3×3 convolutions of ``channels`` (ReLU
    between) predicting the noise, which is subtracted (the last layer starts at zero: the denoiser starts as the
    identity); Adam on batches of ``batch`` random ``patch``² windows, ``steps`` steps, the learning rate rising
    linearly to ``lr`` over ``warmup`` steps (without it a rate that trains this fast kills the ReLUs in the first
    steps), then to 0 along a half cosine; the gradient's norm clipped to ``clip`` (it bites only on strong noise,
    SIDD's, where a seed's run could otherwise stall for a third of its steps).

    References:
        K. Zhang, W. Zuo, L. Zhang, "FFDNet: Toward a Fast and Flexible Solution for CNN-Based Image Denoising",
        IEEE TIP 27(9), 2018 (the folded input).
    """

    layers: int = 5
    channels: int = 32
    fold: int = 2
    steps: int = 400
    batch: int = 16
    patch: int = 48
    lr: float = 2e-3
    warmup: int = 50
    clip: float = 0.05


def make_denoiser(config: Denoiser, seed: int) -> nn.Module:
    planes = 3 * config.fold**2
    widths = [planes] + [config.channels] * (config.layers - 1) + [planes]
    layers: list[nn.Module] = [nn.PixelUnshuffle(config.fold)]
    generator = derived_generator(seed, "denoiser-init")
    for index, (inputs, outputs) in enumerate(pairwise(widths)):
        conv = nn.Conv2d(inputs, outputs, 3, padding=1)
        nn.init.kaiming_uniform_(conv.weight, nonlinearity="relu", generator=generator)
        nn.init.zeros_(conv.bias)
        layers.append(conv)
        if index < config.layers - 1:
            layers.append(nn.ReLU())
    nn.init.zeros_(layers[-1].weight)
    layers.append(nn.PixelShuffle(config.fold))
    return nn.Sequential(*layers)


def denoise(model: nn.Module, noisy: Tensor, fold: int) -> Tensor:
    """``noisy`` less the predicted noise; the image padded (reflected) to a multiple of ``fold`` and cut back."""
    height, width = noisy.shape[-2:]
    padded = F.pad(noisy, (0, -width % fold, 0, -height % fold), mode="reflect")
    return noisy - model(padded)[..., :height, :width]


def patch_plan(sizes: Sequence[tuple[int, int]], config: Denoiser, seed: int) -> Tensor:
    """``(steps, batch, 3)``: image index, top and left of every window (the same for every row of a seed)."""
    generator = derived_generator(seed, "denoiser-patches")
    count = config.steps * config.batch
    index = torch.randint(len(sizes), (count,), generator=generator)
    heights = torch.tensor([h for h, _ in sizes])[index] - config.patch + 1
    widths = torch.tensor([w for _, w in sizes])[index] - config.patch + 1
    top = (torch.rand(count, generator=generator) * heights).long()
    left = (torch.rand(count, generator=generator) * widths).long()
    return torch.stack([index, top, left], 1).view(config.steps, config.batch, 3)


def learning_rate_factor(config: Denoiser, step: int) -> float:
    return min(1.0, (step + 1) / config.warmup) * 0.5 * (1 + math.cos(math.pi * step / config.steps))


def train_denoiser(cleans: Sequence[Tensor], noisies: Sequence[Tensor], config: Denoiser, seed: int) -> nn.Module:
    """A denoiser trained on windows of ``(noisy, clean)`` float ``(3, H, W)`` images in [0, 1]."""
    model = make_denoiser(config, seed)
    optimizer = torch.optim.Adam(model.parameters(), lr=config.lr)
    schedule = torch.optim.lr_scheduler.LambdaLR(optimizer, partial(learning_rate_factor, config))
    side = config.patch
    for step in patch_plan([tuple(c.shape[-2:]) for c in cleans], config, seed).tolist():
        noisy = torch.stack([noisies[i][:, top : top + side, left : left + side] for i, top, left in step])
        clean = torch.stack([cleans[i][:, top : top + side, left : left + side] for i, top, left in step])
        loss = F.mse_loss(denoise(model, noisy, config.fold), clean)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        nn.utils.clip_grad_norm_(model.parameters(), config.clip)
        optimizer.step()
        schedule.step()
    return model.eval()


def psnr_db(image: Tensor, reference: Tensor) -> float:
    return -10 * math.log10(float(F.mse_loss(image, reference)))


def test_psnr(model: nn.Module, pairs: Sequence[tuple[Tensor, Tensor]], fold: int) -> float:
    """Mean PSNR (dB) of the denoised held-out real captures against their clean images, ``(clean, capture)``."""
    with torch.no_grad():
        return statistics.fmean(psnr_db(denoise(model, x[None], fold)[0].clamp(0, 1), c) for c, x in pairs)
