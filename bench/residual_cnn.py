"""The small residual CNN of the training-transfer benches (the denoiser of ``bench_noise_gap.py``, the restorer of
``bench_restoration_transfer.py``): trained on random windows of (degraded, target) image pairs, with the same
initialisation and the same windows for every row of a seed, so that rows differ only in the degraded images they
train on."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import partial
from itertools import pairwise

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from camdegrade._support.seeds import derived_generator

#: The seed streams of the initialisation and the windows (named when the network was the noise bench's denoiser;
#: kept so that its numbers reproduce).
INIT_STREAM, WINDOW_STREAM = "denoiser-init", "denoiser-patches"


@dataclass(frozen=True)
class ResidualCNN:
    """The network and its training: the image folded into ``fold``² planes of lower resolution (pixel unshuffle,
    as FFDNet does: a wider view for the same arithmetic), ``layers`` 3×3 convolutions of ``channels`` (ReLU
    between) predicting the degradation, which is subtracted (the last layer starts at zero: the network starts as
    the identity); Adam on batches of ``batch`` random ``patch``² windows, ``steps`` steps, the learning rate rising
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


def make_network(config: ResidualCNN, seed: int) -> nn.Module:
    planes = 3 * config.fold**2
    widths = [planes] + [config.channels] * (config.layers - 1) + [planes]
    layers: list[nn.Module] = [nn.PixelUnshuffle(config.fold)]
    generator = derived_generator(seed, INIT_STREAM)
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


def apply_network(model: nn.Module, degraded: Tensor, fold: int) -> Tensor:
    """``degraded`` less the predicted degradation; the image padded (reflected) to a multiple of ``fold`` and cut
    back."""
    height, width = degraded.shape[-2:]
    padded = F.pad(degraded, (0, -width % fold, 0, -height % fold), mode="reflect")
    return degraded - model(padded)[..., :height, :width]


def window_plan(sizes: Sequence[tuple[int, int]], config: ResidualCNN, seed: int) -> Tensor:
    """``(steps, batch, 3)``: image index, top and left of every window (the same for every row of a seed)."""
    generator = derived_generator(seed, WINDOW_STREAM)
    count = config.steps * config.batch
    index = torch.randint(len(sizes), (count,), generator=generator)
    heights = torch.tensor([h for h, _ in sizes])[index] - config.patch + 1
    widths = torch.tensor([w for _, w in sizes])[index] - config.patch + 1
    top = (torch.rand(count, generator=generator) * heights).long()
    left = (torch.rand(count, generator=generator) * widths).long()
    return torch.stack([index, top, left], 1).view(config.steps, config.batch, 3)


def learning_rate_factor(config: ResidualCNN, step: int) -> float:
    return min(1.0, (step + 1) / config.warmup) * 0.5 * (1 + math.cos(math.pi * step / config.steps))


def train_network(targets: Sequence[Tensor], degraded: Sequence[Tensor], config: ResidualCNN, seed: int) -> nn.Module:
    """A network trained to take windows of each float ``(3, H, W)`` image in [0, 1] of ``degraded`` to the same
    window of its ``target`` (mean squared error)."""
    model = make_network(config, seed)
    optimizer = torch.optim.Adam(model.parameters(), lr=config.lr)
    schedule = torch.optim.lr_scheduler.LambdaLR(optimizer, partial(learning_rate_factor, config))
    side = config.patch
    for step in window_plan([tuple(t.shape[-2:]) for t in targets], config, seed).tolist():
        inputs = torch.stack([degraded[i][:, top : top + side, left : left + side] for i, top, left in step])
        wanted = torch.stack([targets[i][:, top : top + side, left : left + side] for i, top, left in step])
        loss = F.mse_loss(apply_network(model, inputs, config.fold), wanted)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        nn.utils.clip_grad_norm_(model.parameters(), config.clip)
        optimizer.step()
        schedule.step()
    return model.eval()


def psnr_db(image: Tensor, reference: Tensor) -> float:
    return -10 * math.log10(float(F.mse_loss(image, reference)))
