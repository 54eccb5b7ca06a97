"""Training the domain-shifting network on (clean, captured) image tensors with the paper's recipe.

Resumable (a safetensors checkpoint after every epoch), deterministic for a seed on one machine, and able to run
under ``torchrun`` (DDP: every rank draws the same crops from the shared seed and trains on its share of each
batch, so the global batch and the result match a single process).
"""

from __future__ import annotations

import hashlib
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import torch
import torch.distributed as dist
import torch.nn.functional as F
from torch import Tensor
from tqdm.auto import tqdm

from camdegrade._checks import check_seed
from camdegrade._distributed import rank_and_world_size
from camdegrade._files import check_writable
from camdegrade._pixels import as_unit
from camdegrade.errors import CamdegradeError
from camdegrade.fitting.checkpoint import TrainingState, capture_state, load_checkpoint, save_checkpoint
from camdegrade.metrics import psnr
from camdegrade.network import SIZE_MULTIPLE, DomainShiftNet

#: One aligned pair: (clean, captured), ``(3, H, W)`` each, same size: uint8 (as read), or float in [0, 1].
ImagePair = tuple[Tensor, Tensor]


class FitInterrupted(CamdegradeError):
    """The fit was interrupted (Ctrl-C); the checkpoint of the last finished epoch is kept for ``resume``."""


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
        check_seed(self.seed)

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
    return as_unit(torch.stack(clean_crops)), as_unit(torch.stack(captured_crops))


def evaluate_psnr(network: DomainShiftNet, pairs: Sequence[ImagePair], device: torch.device | str = "cpu") -> float:
    """Mean PSNR (dB) of the network's output against the captures, over full-size pairs."""
    if not pairs:
        return float("nan")
    network.eval()
    scores = []
    with torch.no_grad():
        for clean, captured in pairs:
            output = network(as_unit(clean.to(device)[None]))
            scores.append(psnr(output, captured.to(device)[None]))
    return sum(scores) / len(scores)


def fit_network(
    train: Sequence[ImagePair],
    val: Sequence[ImagePair],
    config: FitConfig | None = None,
    *,
    device: torch.device | str = "cpu",
    callback: Callable[[EpochResult], None] | None = None,
    checkpoint: str | os.PathLike[str] | None = None,
    resume: bool = False,
    progress: bool = False,
    pair_names: Sequence[str] | None = None,
    initial: DomainShiftNet | None = None,
) -> tuple[DomainShiftNet, list[EpochResult]]:
    """Train a :class:`DomainShiftNet` mapping clean → captured; return the best epoch's weights (by ``val`` PSNR,
    or by training loss when ``val`` is empty) and the per-epoch history.

    Same pairs, config and machine → identical weights: initialisation and crops come from ``config.seed``.
    With ``checkpoint``, the full training state is written there after every epoch (atomically); ``resume=True``
    continues from it, giving the same weights as an uninterrupted fit; the checkpoint must exist and hold the same
    recipe and pairs (:func:`pairs_fingerprint` of ``train``, ``val`` and ``pair_names``), otherwise a
    :class:`~camdegrade.errors.CamdegradeError` says which differs. Ctrl-C raises :class:`FitInterrupted`
    after the last finished epoch's checkpoint is on disk. Under ``torch.distributed`` (e.g. ``torchrun``), each
    rank trains on its share of every batch and only rank 0 writes files.

    ``initial``: start from this network's weights (copied; it is not changed) instead of a fresh initialisation
    from ``config.seed``, e.g. to refit a profile's network on new pairs. It must have the width of the network
    trained here (:class:`DomainShiftNet`'s default), else a ``ValueError``. A resumed fit continues from its
    checkpoint's weights.
    """
    config = config or FitConfig()
    _check_pairs(train, config.crop)
    rank, world = rank_and_world_size()
    _check_initial(initial)
    if config.batch_size % world:
        raise ValueError(f"batch_size ({config.batch_size}) must be divisible by the number of processes ({world})")
    if checkpoint is not None and rank == 0:
        check_writable(checkpoint)  # before training, not after its first epoch
    fingerprint = pairs_fingerprint(train, val, pair_names)
    network, optimizer, scheduler, generator = _new_training(config, device, initial)
    state = _initial_state(network, optimizer, scheduler, generator, config, checkpoint, resume, fingerprint)
    model = _distributed(network, device) if world > 1 else network
    epochs = tqdm(
        range(state.epoch, config.epochs),
        initial=state.epoch,
        total=config.epochs,
        desc="fit",
        unit="epoch",
        disable=not progress or rank != 0,
    )
    try:
        for epoch in epochs:
            lr = optimizer.param_groups[0]["lr"]
            loss = _train_one_epoch(model, optimizer, train, config, generator, device, rank, world)
            scheduler.step()
            score = evaluate_psnr(network, val, device) if val else -loss
            is_best = score > state.best_score
            result = EpochResult(epoch + 1, loss, score if val else float("nan"), lr, is_best)
            state = capture_state(
                network,
                optimizer,
                scheduler,
                generator,
                epoch=epoch + 1,
                best_score=max(score, state.best_score),
                best_network={k: v.detach().clone() for k, v in network.state_dict().items()}
                if is_best
                else state.best_network,
                history=[*state.history, asdict(result)],
                config=config.as_dict(),
                data=fingerprint,
            )
            if checkpoint is not None and rank == 0:
                save_checkpoint(state, checkpoint)
            epochs.set_postfix(loss=f"{loss:.5f}", val_psnr=f"{result.val_psnr:.2f}")
            if callback is not None:
                callback(result)
    except KeyboardInterrupt:
        where = f"; resume with the same checkpoint ({checkpoint})" if checkpoint else ""
        raise FitInterrupted(f"fit interrupted after epoch {state.epoch} of {config.epochs}{where}") from None
    if state.best_network is not None:
        network.load_state_dict(state.best_network)
    return network.cpu().eval(), [EpochResult(**entry) for entry in state.history]


def _check_initial(initial: DomainShiftNet | None) -> None:
    if initial is not None and not isinstance(initial, DomainShiftNet):
        raise TypeError(f"initial must be a DomainShiftNet or None, got {type(initial).__name__}")


def _new_training(config: FitConfig, device: torch.device | str, initial: DomainShiftNet | None = None):
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(config.seed)
        network = DomainShiftNet()
    if initial is not None:
        if initial.width != network.width:
            raise ValueError(
                f"initial must be a DomainShiftNet of width {network.width} (the width fitted here), got "
                f"width={initial.width}"
            )
        network.load_state_dict(initial.state_dict())  # copies the values, from any device
    network.to(device)
    optimizer = torch.optim.Adam(network.parameters(), lr=config.lr)
    scheduler = torch.optim.lr_scheduler.StepLR(optimizer, step_size=config.lr_halving_epochs, gamma=0.5)
    return network, optimizer, scheduler, torch.Generator().manual_seed(config.seed)


def pairs_fingerprint(train: Sequence[ImagePair], val: Sequence[ImagePair], names: Sequence[str] | None = None) -> str:
    """A short hash of the pairs a fit uses: their number, names, sizes, dtypes and a grid of about 4096 sampled
    pixels per image (cheap: no image is copied whole), so a resume can tell other pairs from the same ones."""
    digest = hashlib.blake2b(digest_size=8)
    for part, pairs in (("train", train), ("val", val)):
        digest.update(f"{part}:{len(pairs)};".encode())
        for image in (image for pair in pairs for image in pair):
            step = max(1, math.isqrt(image.shape[-2] * image.shape[-1] // _SAMPLED_PIXELS))
            sample = image.detach()[..., ::step, ::step].cpu().contiguous()
            digest.update(f"{tuple(image.shape)}{image.dtype};".encode())
            digest.update(sample.numpy().tobytes())
    for name in names or ():
        digest.update(f"{name}\0".encode())
    return digest.hexdigest()


_SAMPLED_PIXELS = 4096


def _initial_state(
    network, optimizer, scheduler, generator, config, checkpoint, resume, fingerprint: str
) -> TrainingState:
    fresh = capture_state(
        network,
        optimizer,
        scheduler,
        generator,
        epoch=0,
        best_score=-math.inf,
        best_network=None,
        config=config.as_dict(),
        data=fingerprint,
    )
    if not resume:
        return fresh
    if checkpoint is None:
        raise ValueError("resume=True needs checkpoint=PATH")
    if not Path(checkpoint).exists():
        raise CamdegradeError(
            f"resume: checkpoint {str(checkpoint)!r} does not exist; check its path, or start a new fit without resume"
        )
    state = load_checkpoint(checkpoint)
    recipe = {k: v for k, v in config.as_dict().items() if k != "epochs"}
    saved = {k: v for k, v in state.config.items() if k != "epochs"}
    if recipe != saved:
        raise ValueError(f"checkpoint {str(checkpoint)!r} was written with a different recipe: {saved}, now {recipe}")
    if state.data != fingerprint:
        raise CamdegradeError(
            f"checkpoint {str(checkpoint)!r} was written for other training pairs (fingerprint "
            f"{state.data or 'none recorded'}, these pairs give {fingerprint}); resume with the same pairs, or start "
            "a new fit without resume"
        )
    network.load_state_dict(state.network)
    optimizer.load_state_dict(state.optimizer)
    scheduler.load_state_dict(state.scheduler)
    generator.set_state(state.generator)
    return state


def _train_one_epoch(model, optimizer, train, config, generator, device, rank: int, world: int) -> float:
    model.train()
    total_crops = config.crops_per_pair * len(train)
    loss_sum = 0.0
    for start in range(0, total_crops, config.batch_size):
        count = min(config.batch_size, total_crops - start)
        clean, captured = random_crop_batch(train, config.crop, count, generator)  # same crops on every rank
        clean, captured = clean[rank::world].to(device), captured[rank::world].to(device)
        optimizer.zero_grad(set_to_none=True)
        loss = F.mse_loss(model(clean), captured, reduction="sum") / (count * clean[0].numel() / world)
        loss.backward()
        optimizer.step()
        loss_sum += _global_sum(loss.detach() * count / world)  # this rank's squared error per crop element
    return loss_sum / total_crops


def _distributed(network: DomainShiftNet, device: torch.device | str) -> torch.nn.Module:
    device = torch.device(device)
    device_ids = (
        [device.index if device.index is not None else torch.cuda.current_device()] if device.type == "cuda" else None
    )
    return torch.nn.parallel.DistributedDataParallel(network, device_ids=device_ids)


def _global_sum(value: Tensor) -> float:
    if dist.is_available() and dist.is_initialized():
        value = value.clone()
        dist.all_reduce(value)
    return float(value)


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
