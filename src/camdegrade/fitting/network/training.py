"""Training the domain-shifting network on (clean, captured) image tensors with a recipe
(:class:`~camdegrade.fitting.FitConfig`): the training step, early stopping on the validation PSNR.

Resumable (a safetensors checkpoint after every epoch), deterministic for a seed on one machine, and able to run
under ``torchrun`` (DDP: every rank draws the same crops from the shared seed and trains on its share of each
batch, so the global batch and the result match a single process).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import torch
import torch.distributed as dist
import torch.nn.functional as F
from torch import Tensor
from tqdm.auto import tqdm

from camdegrade._runtime.distributed import is_distributed, rank_and_world_size
from camdegrade._support.files import check_writable
from camdegrade._support.pixels import as_unit
from camdegrade._support.recipes import TRAIN_PRECISIONS
from camdegrade._support.seeds import derive_seed, derived_generator
from camdegrade.effects import Resolution
from camdegrade.errors import FitInterrupted
from camdegrade.fitting.network.checkpoint import (
    TrainingState,
    capture_state,
    initial_state,
    pairs_fingerprint,
    save_checkpoint,
)
from camdegrade.fitting.recipe import FitConfig
from camdegrade.measures.metrics import psnr
from camdegrade.network import SIZE_MULTIPLE, ShiftNetwork, build_network
from camdegrade.network.inference import native_bfloat16, run_network
from camdegrade.pairs.pairset import ImagePair

__all__ = [
    "MIN_PROGRESS_DB",
    "EpochResult",
    "FitInterrupted",
    "evaluate_psnr",
    "fit_network",
    "new_network",
    "random_crop_batch",
    "training_dtype",
]


@dataclass(frozen=True)
class EpochResult:
    """What one epoch did; passed to the progress callback."""

    epoch: int
    train_loss: float
    val_psnr: float
    lr: float
    is_best: bool


def random_crop_batch(
    pairs: Sequence[ImagePair], crop: int, count: int, generator: torch.Generator, *, step: int = 1
) -> ImagePair:
    """``count`` random aligned windows, as float ``(count, 3, crop, crop)`` clean and captured batches in [0, 1],
    their corners on multiples of ``step`` (a sensor grid's period, so each window sees it in the whole image's
    phase)."""
    if isinstance(step, bool) or not isinstance(step, int) or step < 1:
        raise ValueError(f"step must be a positive integer, got step={step!r}")
    which = torch.randint(len(pairs), (count,), generator=generator).tolist()
    clean_crops, captured_crops = [], []
    for index in which:
        clean, captured = pairs[index]
        height, width = clean.shape[-2:]
        top = step * int(torch.randint((height - crop) // step + 1, (1,), generator=generator))
        left = step * int(torch.randint((width - crop) // step + 1, (1,), generator=generator))
        clean_crops.append(clean[:, top : top + crop, left : left + crop])
        captured_crops.append(captured[:, top : top + crop, left : left + crop])
    return as_unit(torch.stack(clean_crops)), as_unit(torch.stack(captured_crops))


def evaluate_psnr(
    network: ShiftNetwork,
    pairs: Sequence[ImagePair],
    device: torch.device | str = "cpu",
    after: torch.nn.Module | None = None,
) -> float:
    """Mean PSNR (dB) of the network's output (through ``after``, a fixed stage, when given) against the captures,
    over full-size pairs."""
    if not pairs:
        return float("nan")
    network.eval()
    scores = []
    with torch.no_grad():
        for clean, captured in pairs:
            output = run_network(network, as_unit(clean.to(device)[None]), "float32")
            if after is not None:
                output = after(output)
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
    initial: ShiftNetwork | None = None,
    after: Resolution | None = None,
) -> tuple[ShiftNetwork, list[EpochResult]]:
    """Train a network of ``config.arch`` mapping clean → captured; return the best epoch's weights (by ``val``
    PSNR, or by training loss when ``val`` is empty) and the per-epoch history.

    Same pairs, config and machine → identical weights: initialisation and crops come from ``config.seed``.
    With ``config.patience``, the fit stops once the validation PSNR has not risen by 0.01 dB for that many
    epochs (never without ``val``). With ``checkpoint``, the full training state is written there after every
    epoch (atomically); ``resume=True`` continues from it, giving the same weights as an uninterrupted fit; the
    checkpoint must exist and hold the same recipe and pairs (:func:`pairs_fingerprint` of ``train``, ``val`` and
    ``pair_names``), otherwise a :class:`~camdegrade.errors.CamdegradeError` says which differs. Ctrl-C raises
    :class:`FitInterrupted` after the last finished epoch's checkpoint is on disk. Under ``torch.distributed``
    (e.g. ``torchrun``), each rank trains on its share of every batch and only rank 0 writes files.
    ``progress`` shows a bar over the fit's steps with the time left.

    ``initial``: start from this network's weights (copied; it is not changed) instead of a fresh initialisation
    from ``config.seed``, e.g. to refit a profile's network on new pairs, or a linear baseline. It must have the
    architecture and width of the network trained here (``config.arch``, ``config.width``), else a
    ``ValueError``. Its validation PSNR is the score every epoch must beat: a fit that never does returns it
    unchanged (best epoch 0), never worse than where it started. A resumed fit continues from its checkpoint's
    weights.

    ``after``: a sensor-resolution stage the camera applies after what the network models: the network is trained
    (and scored) through it, on windows cropped on its grid (:attr:`~camdegrade.effects.Resolution.period`), so
    it learns the image before the sensor's sampling; the profile runs the stage after the network.
    """
    config = config or FitConfig()
    _check_pairs(train, config.crop)
    _check_initial(initial)
    rank, world = rank_and_world_size()
    if config.batch_size % world:
        raise ValueError(f"batch_size ({config.batch_size}) must be divisible by the number of processes ({world})")
    if checkpoint is not None and rank == 0:
        check_writable(checkpoint)  # before training, not after its first epoch
    fingerprint = pairs_fingerprint(train, val, pair_names)
    if after is not None:  # a checkpoint trained through one sensor must not resume through another, or none
        fingerprint += f" through a sensor at {float(after.scale):.4g}x"
    network, optimizer, scheduler, generator = _new_training(config, device, initial)
    start = _starting_score(network, val, device, after) if initial is not None else None
    state = initial_state(network, optimizer, scheduler, generator, config, checkpoint, resume, fingerprint, start)
    model = _distributed(network, device) if world > 1 else network
    step = _TrainStep(model, optimizer, config, device, world, after)
    bar = _progress_bar(config, len(train), state.epoch, enabled=progress and rank == 0)
    try:
        while state.epoch < config.epochs and not (val and _patience_spent(state.history, config.patience)):
            loss = _train_one_epoch(step, train, generator, rank, bar)
            state = _end_epoch(state, network, optimizer, scheduler, generator, val, loss, device, after)
            if checkpoint is not None and rank == 0:
                save_checkpoint(state, checkpoint)
            result = EpochResult(**state.history[-1])
            bar.set_postfix(epoch=result.epoch, loss=f"{loss:.5f}", val_psnr=f"{result.val_psnr:.2f}")
            if callback is not None:
                callback(result)
    except KeyboardInterrupt:
        where = f"; resume with the same checkpoint ({checkpoint})" if checkpoint else ""
        raise FitInterrupted(f"fit interrupted after epoch {state.epoch} of {config.epochs}{where}") from None
    finally:
        bar.close()
    if state.best_network is not None:
        network.load_state_dict(state.best_network)
    return network.cpu().eval(), [EpochResult(**entry) for entry in state.history]


#: A validation PSNR must rise by this much (dB) to count as progress for early stopping.
MIN_PROGRESS_DB = 0.01


def _patience_spent(history: Sequence[dict[str, Any]], patience: int) -> bool:
    """Whether the last ``patience`` epochs of ``history`` brought no progress (:data:`MIN_PROGRESS_DB`)."""
    if patience <= 0:
        return False
    reference, last_progress = -math.inf, 0
    for entry in history:
        if entry["val_psnr"] > reference + MIN_PROGRESS_DB:
            reference, last_progress = entry["val_psnr"], entry["epoch"]
    return len(history) - last_progress >= patience


def _end_epoch(
    state, network, optimizer, scheduler, generator, val, loss: float, device, after: Resolution | None = None
) -> TrainingState:
    """The state after an epoch: the schedule's step, the validation score, the best weights so far."""
    lr = optimizer.param_groups[0]["lr"]
    scheduler.step()
    # Every rank takes rank 0's score, so that all agree on the best epoch and on when to stop.
    score = _from_rank0(evaluate_psnr(network, val, device, after=after) if val else -loss, device)
    is_best = score > state.best_score
    result = EpochResult(state.epoch + 1, loss, score if val else float("nan"), lr, is_best)
    best = {k: v.detach().clone() for k, v in network.state_dict().items()} if is_best else state.best_network
    return capture_state(
        network,
        optimizer,
        scheduler,
        generator,
        epoch=state.epoch + 1,
        best_score=max(score, state.best_score),
        best_network=best,
        history=[*state.history, asdict(result)],
        config=state.config,
        data=state.data,
    )


def _progress_bar(config: FitConfig, pairs: int, done_epochs: int, *, enabled: bool) -> tqdm:
    """A bar over every step of the fit (so its time left is right from the first epoch on)."""
    per_epoch = -(-config.crops_per_pair * pairs // config.batch_size)
    return tqdm(
        total=per_epoch * config.epochs,
        initial=per_epoch * done_epochs,
        desc="fit",
        unit="step",
        disable=not enabled,
    )


def _check_initial(initial: ShiftNetwork | None) -> None:
    if initial is not None and not isinstance(initial, ShiftNetwork):
        raise TypeError(f"initial must be a DomainShiftNet, a LocalAffineNet or None, got {type(initial).__name__}")


def _starting_score(
    network: ShiftNetwork, val: Sequence[ImagePair], device, after: Resolution | None = None
) -> tuple[float, dict[str, Tensor]] | None:
    """The validation PSNR of the network a fit starts from and its weights: the score to beat (``None`` without
    validation pairs)."""
    if not val:
        return None
    score = _from_rank0(evaluate_psnr(network, val, device, after=after), device)
    return score, {k: v.detach().clone() for k, v in network.state_dict().items()}


def new_network(config: FitConfig) -> ShiftNetwork:
    """A network of ``config.arch`` and ``config.width``, initialised from ``config.seed``."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(derive_seed(config.seed, "network-init"))
        return build_network(config.arch, config.width, config.upsample, curves=config.curves == "channel")


def _new_training(config: FitConfig, device: torch.device | str, initial: ShiftNetwork | None = None):
    network = new_network(config)
    if initial is not None:
        curves, wanted = getattr(initial, "curves", False), getattr(network, "curves", False)
        if initial.arch != network.arch or initial.width != network.width or curves != wanted:
            raise ValueError(
                f"initial must be a network of arch {network.arch!r}, width {network.width} and curves {wanted} "
                f"(the recipe's), got arch={initial.arch!r}, width={initial.width}, curves={curves}"
            )
        network.load_state_dict(initial.state_dict())  # copies the values, from any device
    network.to(device)
    optimizer = torch.optim.Adam(network.parameters(), lr=config.lr)
    if config.schedule == "cosine":
        scheduler: torch.optim.lr_scheduler.LRScheduler = torch.optim.lr_scheduler.CosineAnnealingLR(
            optimizer, T_max=config.epochs
        )
    else:
        scheduler = torch.optim.lr_scheduler.StepLR(optimizer, step_size=config.lr_halving_epochs, gamma=0.5)
    return network, optimizer, scheduler, derived_generator(config.seed, "training-crops")


class _TrainStep:
    """One optimizer step on a batch of crops: channels-last input (oneDNN's fastest convolutions on the CPU),
    bfloat16 autocast where the recipe asks for it, loss and optimizer in float32."""

    def __init__(
        self, model: torch.nn.Module, optimizer, config: FitConfig, device, world: int, after: Resolution | None = None
    ) -> None:
        self.model, self.optimizer, self.config, self.world = model, optimizer, config, world
        self.after = after.to(device) if after is not None else None
        self.crop_step = after.period if after is not None else 1
        self.crop = _sensor_crop(config.crop, after) if after is not None else config.crop
        self.device = torch.device(device)
        self.autocast = training_dtype(config.precision, self.device) == torch.bfloat16

    def __call__(self, clean: Tensor, captured: Tensor, count: int) -> Tensor:
        clean = clean.to(self.device).contiguous(memory_format=torch.channels_last)
        captured = captured.to(self.device)
        self.optimizer.zero_grad(set_to_none=True)
        with torch.autocast(self.device.type, dtype=torch.bfloat16, enabled=self.autocast):
            output = self.model(clean)
        if self.after is not None:
            output = self.after(output.float())
        loss = F.mse_loss(output.float(), captured, reduction="sum") / (count * captured[0].numel() / self.world)
        loss.backward()
        self.optimizer.step()
        return loss.detach()


def _sensor_crop(crop: int, sensor: Resolution) -> int:
    """The training window for a network trained through ``sensor``: ``crop`` rounded down to a whole number of
    sensor periods that is also a multiple of the network's :data:`~camdegrade.network.SIZE_MULTIPLE`, so the stage
    samples each window on the whole image's grid (a 64-px window at scale 1/3 would hold 21.3 sensor pixels)."""
    unit = math.lcm(SIZE_MULTIPLE, sensor.period)
    if crop < 2 * unit:
        raise ValueError(
            f"crop must hold two sensor periods of a multiple of {SIZE_MULTIPLE} px at sensor_scale "
            f"{float(sensor.scale):.4g} (period {sensor.period} px): at least {2 * unit}, got crop={crop}"
        )
    return crop // unit * unit


def training_dtype(precision: str, device: torch.device) -> torch.dtype:
    """The dtype the convolutions of a fit run in: bfloat16 when asked, or for ``"auto"`` where ``device``
    computes it natively (:func:`camdegrade.network.inference.native_bfloat16`); float32 otherwise."""
    if precision not in TRAIN_PRECISIONS:
        raise ValueError(f"precision must be one of {TRAIN_PRECISIONS}, got precision={precision!r}")
    native = precision == "auto" and native_bfloat16(device)
    return torch.bfloat16 if precision == "bfloat16" or native else torch.float32


def _train_one_epoch(step: _TrainStep, train, generator, rank: int, bar: tqdm) -> float:
    step.model.train()
    config, world = step.config, step.world
    total_crops = config.crops_per_pair * len(train)
    loss_sum = 0.0
    for start in range(0, total_crops, config.batch_size):
        count = min(config.batch_size, total_crops - start)
        # the same crops on every rank
        clean, captured = random_crop_batch(train, step.crop, count, generator, step=step.crop_step)
        loss = step(clean[rank::world], captured[rank::world], count)
        loss_sum += _global_sum(loss * count / world)  # this rank's squared error per crop element
        bar.update()
    return loss_sum / total_crops


def _distributed(network: ShiftNetwork, device: torch.device | str) -> torch.nn.Module:
    device = torch.device(device)
    device_ids = (
        [device.index if device.index is not None else torch.cuda.current_device()] if device.type == "cuda" else None
    )
    return torch.nn.parallel.DistributedDataParallel(network, device_ids=device_ids)


def _from_rank0(value: float, device: torch.device | str) -> float:
    if not is_distributed():
        return value
    tensor = torch.tensor([value], dtype=torch.float64, device=device)
    dist.broadcast(tensor, src=0)
    return float(tensor)


def _global_sum(value: Tensor) -> float:
    if is_distributed():
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
