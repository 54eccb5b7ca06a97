"""Fitting the domain-shifting network on (clean, captured) pairs with the paper's recipe."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from camdegrade.metrics import psnr
from camdegrade.network import SIZE_MULTIPLE, DomainShiftNet

#: One aligned pair: (clean, captured), uint8 ``(3, H, W)`` each, same size.
ImagePair = tuple[Tensor, Tensor]


@dataclass(frozen=True)
class FitConfig:
    """Training recipe. Defaults are the paper's: L2 loss, Adam at lr 0.01 halved every 30 epochs, 100 epochs,
    batch 32 — on random ``crop``×``crop`` windows of the full-resolution pairs instead of squashed resizes.

    An epoch draws ``crops_per_pair`` random windows from every training pair.
    """

    epochs: int = 100
    crop: int = 128
    batch_size: int = 32
    lr: float = 0.01
    lr_halving_epochs: int = 30
    crops_per_pair: int = 8
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("epochs", "crop", "batch_size", "lr_halving_epochs", "crops_per_pair"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {name}={value!r}")
        if self.crop % SIZE_MULTIPLE:
            raise ValueError(f"crop must be a multiple of {SIZE_MULTIPLE}, got crop={self.crop}")
        if not (isinstance(self.lr, (int, float)) and math.isfinite(self.lr) and self.lr > 0):
            raise ValueError(f"lr must be a positive number, got lr={self.lr!r}")

    def as_dict(self) -> dict[str, int | float]:
        return asdict(self)


@dataclass(frozen=True)
class EpochResult:
    """What one epoch did; passed to the progress callback."""

    epoch: int
    train_loss: float
    val_psnr: float
    lr: float
    is_best: bool


def random_crop_batch(pairs: Sequence[ImagePair], crop: int, count: int, generator: torch.Generator) -> ImagePair:
    """``count`` random aligned windows, as float ``(count, 3, crop, crop)`` clean and captured batches in [0, 1]."""
    which = torch.randint(len(pairs), (count,), generator=generator).tolist()
    clean_crops, captured_crops = [], []
    for index in which:
        clean, captured = pairs[index]
        height, width = clean.shape[-2:]
        top = int(torch.randint(height - crop + 1, (1,), generator=generator))
        left = int(torch.randint(width - crop + 1, (1,), generator=generator))
        clean_crops.append(clean[:, top : top + crop, left : left + crop])
        captured_crops.append(captured[:, top : top + crop, left : left + crop])
    return torch.stack(clean_crops).float() / 255.0, torch.stack(captured_crops).float() / 255.0


def evaluate_psnr(network: DomainShiftNet, pairs: Sequence[ImagePair], device: torch.device | str = "cpu") -> float:
    """Mean PSNR (dB) of the network's output against the captures, over full-size pairs."""
    if not pairs:
        return float("nan")
    network.eval()
    scores = []
    with torch.no_grad():
        for clean, captured in pairs:
            output = network(clean.to(device)[None].float() / 255.0)
            scores.append(psnr(output, captured.to(device)[None]))
    return sum(scores) / len(scores)


def fit_network(
    train: Sequence[ImagePair],
    val: Sequence[ImagePair],
    config: FitConfig | None = None,
    *,
    device: torch.device | str = "cpu",
    callback: Callable[[EpochResult], None] | None = None,
) -> tuple[DomainShiftNet, list[EpochResult]]:
    """Train a :class:`DomainShiftNet` mapping clean → captured; return the best epoch's weights (by ``val`` PSNR,
    or the last epoch when ``val`` is empty) and the per-epoch history.

    Same pairs, config and machine → identical weights: initialisation and crops come from ``config.seed``.
    """
    config = config or FitConfig()
    _check_pairs(train, config.crop)
    generator = torch.Generator().manual_seed(config.seed)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(config.seed)
        network = DomainShiftNet()
    network.to(device)
    optimizer = torch.optim.Adam(network.parameters(), lr=config.lr)
    schedule = torch.optim.lr_scheduler.StepLR(optimizer, step_size=config.lr_halving_epochs, gamma=0.5)
    best_score, best_state, history = -math.inf, None, []
    for epoch in range(config.epochs):
        lr = optimizer.param_groups[0]["lr"]
        loss = _train_one_epoch(network, optimizer, train, config, generator, device)
        schedule.step()
        score = evaluate_psnr(network, val, device) if val else -loss
        is_best = score > best_score
        if is_best:
            best_score, best_state = score, {k: v.detach().clone() for k, v in network.state_dict().items()}
        result = EpochResult(epoch + 1, loss, score if val else float("nan"), lr, is_best)
        history.append(result)
        if callback is not None:
            callback(result)
    if best_state is not None:
        network.load_state_dict(best_state)
    return network.cpu().eval(), history


def _train_one_epoch(
    network: DomainShiftNet,
    optimizer: torch.optim.Optimizer,
    train: Sequence[ImagePair],
    config: FitConfig,
    generator: torch.Generator,
    device: torch.device | str,
) -> float:
    network.train()
    total_crops = config.crops_per_pair * len(train)
    losses = []
    for start in range(0, total_crops, config.batch_size):
        count = min(config.batch_size, total_crops - start)
        clean, captured = random_crop_batch(train, config.crop, count, generator)
        optimizer.zero_grad(set_to_none=True)
        loss = F.mse_loss(network.forward_aligned(clean.to(device)), captured.to(device))
        loss.backward()
        optimizer.step()
        losses.append(loss.item() * count)
    return sum(losses) / total_crops


def _check_pairs(pairs: Sequence[ImagePair], crop: int) -> None:
    if not pairs:
        raise ValueError("train must hold at least one (clean, captured) pair, got none")
    for index, (clean, captured) in enumerate(pairs):
        if clean.shape != captured.shape or clean.ndim != 3 or clean.shape[0] != 3:
            raise ValueError(
                f"pair {index}: clean and captured must both be (3, H, W) of the same size, got "
                f"{tuple(clean.shape)} and {tuple(captured.shape)}"
            )
        if min(clean.shape[-2:]) < crop:
            raise ValueError(f"pair {index}: image {tuple(clean.shape[-2:])} is smaller than crop={crop}")
