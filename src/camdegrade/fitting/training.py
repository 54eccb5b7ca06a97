"""Training the domain-shifting network on (clean, captured) image tensors: the recipes (camdegrade's fast one and
the paper's), the training step, early stopping on the validation PSNR.

Resumable (a safetensors checkpoint after every epoch), deterministic for a seed on one machine, and able to run
under ``torchrun`` (DDP: every rank draws the same crops from the shared seed and trains on its share of each
batch, so the global batch and the result match a single process).
"""

from __future__ import annotations

import hashlib
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any

import torch
import torch.distributed as dist
import torch.nn.functional as F
from torch import Tensor
from tqdm.auto import tqdm

from camdegrade import _recipes
from camdegrade._checks import check_seed
from camdegrade._distributed import is_distributed, rank_and_world_size
from camdegrade._files import check_writable
from camdegrade._pixels import as_unit
from camdegrade._recipes import CURVES, FAST, MIN_SENSOR_SCALE, RECIPES, TEXTURES, TRAINING_FIELDS, UPSAMPLINGS
from camdegrade._seeds import derive_seed, derived_generator
from camdegrade.effects import Resolution, check_effect_names
from camdegrade.errors import CamdegradeError
from camdegrade.fitting.checkpoint import TrainingState, capture_state, load_checkpoint, save_checkpoint
from camdegrade.inference import native_bfloat16, run_network
from camdegrade.metrics import psnr
from camdegrade.network import ARCHITECTURES, MAX_WIDTH, SIZE_MULTIPLE, ShiftNetwork, build_network

__all__ = [
    "MIN_PROGRESS_DB",
    "SCHEDULES",
    "TRAIN_PRECISIONS",
    "EpochResult",
    "FitConfig",
    "FitInterrupted",
    "ImagePair",
    "evaluate_psnr",
    "fit_network",
    "new_network",
    "pairs_fingerprint",
    "random_crop_batch",
    "resolve_recipe",
    "training_dtype",
]

#: One aligned pair: (clean, captured), ``(3, H, W)`` each, same size: uint8 (as read), or float in [0, 1].
ImagePair = tuple[Tensor, Tensor]


class FitInterrupted(CamdegradeError):
    """The fit was interrupted (Ctrl-C); the checkpoint of the last finished epoch is kept for ``resume``."""


#: How the learning rate moves: ``"step"`` halves it every ``lr_halving_epochs`` epochs (the paper's schedule);
#: ``"cosine"`` lowers it from ``lr`` to 0 along a half cosine over ``epochs``, one step per epoch.
SCHEDULES: tuple[str, ...] = _recipes.SCHEDULES
#: Arithmetic of the forward and backward passes: ``"bfloat16"`` autocasts the convolutions (float32 weights,
#: optimizer and loss); ``"auto"`` does so where the device computes bfloat16 natively, else float32.
TRAIN_PRECISIONS: tuple[str, ...] = _recipes.TRAIN_PRECISIONS


@dataclass(frozen=True)
class FitConfig:
    """A fitting recipe: L2 loss and Adam on random ``crop``×``crop`` windows of the full-resolution pairs (instead of
    the paper's squashed resizes); an epoch draws ``crops_per_pair`` windows from every training pair; a share
    ``val_fraction`` of the scenes validates; the ``effects`` stages are fitted after the network.

    The defaults are camdegrade's fast recipe (``RECIPES["fast"]``, :mod:`camdegrade._recipes`): batches of 8, Adam on
    a cosine schedule, stopping early once the validation PSNR has not risen for ``patience`` epochs.
    ``FitConfig.recipe("paper")`` is the paper's: 100 epochs, Adam at lr 0.01 halved every 30 epochs, batch 32,
    no early stopping. Either trains in bfloat16 where the device computes it natively (``precision="auto"``).
    Change values with :meth:`replace`: ``FitConfig.recipe("fast").replace(epochs=3)``.

    Args:
        patience: stop after this many epochs without a better validation PSNR (by at least 0.01 dB); 0 never
            stops early. The best epoch's weights are returned either way.
        schedule: one of :data:`SCHEDULES`; ``lr_halving_epochs`` is used by ``"step"`` only.
        precision: one of :data:`TRAIN_PRECISIONS`.
        width: the network's width (the paper's 64).
        arch: the network (:data:`~camdegrade.network.ARCHITECTURES`): ``"local_affine"`` (the fast recipe's; no
            4-pixel grid) or ``"paper"`` (the paper recipe's, :class:`~camdegrade.network.DomainShiftNet`).
        upsample: how ``local_affine`` brings its colour field to full resolution, one of
            :data:`~camdegrade.network.FIELD_UPSAMPLING` (the paper network ignores it).
        curves: ``local_affine``'s pointwise curves, one of :data:`~camdegrade._recipes.CURVES`: ``"channel"`` (the
            fast recipe's) or ``"none"`` (the paper recipe's; the paper network ignores it).
        val_fraction: share of *scenes* held out for choosing the best epoch and checking the effect stages
            (``fit_profile``; ``distill_profile`` holds out that share of its images, at least one).
        effects: effect stages ``fit_profile`` fits after the network (names from ``EFFECTS``; ``()``: network only).
            ``distill_profile`` copies its teacher's stages instead.
        texture: one of :data:`~camdegrade._recipes.TEXTURES`: ``"match"`` (the fast recipe's) adds a blur and a
            sharpening after the effect stages where they bring the band power closer to the captures' on the
            validation pairs (:mod:`camdegrade.fitting.texture`); ``"none"`` (the paper recipe's) never does.
        sensor_scale: a camera that upscales (its sensor, or the mode it is used in, has fewer pixels than its
            output): the sensor's resolution relative to the output, from 0.125 to 1. Below 1, ``fit_profile``
            trains a ``local_affine`` network through a :class:`~camdegrade.effects.Resolution` stage of that scale
            and keeps the stage after it; ``"auto"`` (the fast recipe's): the scale found from the training
            captures (:mod:`camdegrade.fitting.resolution`), or none; 1 (the paper recipe's): none.
    """

    epochs: int = FAST["epochs"]
    crop: int = FAST["crop"]
    batch_size: int = FAST["batch_size"]
    lr: float = FAST["lr"]
    lr_halving_epochs: int = FAST["lr_halving_epochs"]
    crops_per_pair: int = FAST["crops_per_pair"]
    seed: int = FAST["seed"]
    schedule: str = FAST["schedule"]
    patience: int = FAST["patience"]
    precision: str = FAST["precision"]
    width: int = FAST["width"]
    arch: str = FAST["arch"]
    upsample: str = FAST["upsample"]
    curves: str = FAST["curves"]
    val_fraction: float = FAST["val_fraction"]
    effects: tuple[str, ...] = FAST["effects"]
    texture: str = FAST["texture"]
    sensor_scale: str | float = FAST["sensor_scale"]

    def __post_init__(self) -> None:
        for name in ("epochs", "crop", "batch_size", "lr_halving_epochs", "crops_per_pair", "width"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {name}={value!r}")
        if self.width > MAX_WIDTH:
            raise ValueError(f"width must be at most {MAX_WIDTH}, got width={self.width}")
        if isinstance(self.patience, bool) or not isinstance(self.patience, int) or self.patience < 0:
            raise ValueError(f"patience must be an integer >= 0 (0: no early stopping), got patience={self.patience!r}")
        if self.crop % SIZE_MULTIPLE:
            raise ValueError(f"crop must be a multiple of {SIZE_MULTIPLE}, got crop={self.crop}")
        if not (isinstance(self.lr, (int, float)) and math.isfinite(self.lr) and self.lr > 0):
            raise ValueError(f"lr must be a positive number, got lr={self.lr!r}")
        choices = (
            ("schedule", SCHEDULES),
            ("precision", TRAIN_PRECISIONS),
            ("arch", tuple(ARCHITECTURES)),
            ("texture", TEXTURES),
            ("upsample", UPSAMPLINGS),
            ("curves", CURVES),
        )
        for name, allowed in choices:
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name} must be one of {allowed}, got {name}={getattr(self, name)!r}")
        scale = self.sensor_scale
        number = not isinstance(scale, bool) and isinstance(scale, (int, float))
        if scale != "auto" and not (number and MIN_SENSOR_SCALE <= scale <= 1):
            raise ValueError(
                f"sensor_scale must be 'auto' or a number from {MIN_SENSOR_SCALE} to 1, got sensor_scale={scale!r}"
            )
        if number and scale < 1 and self.arch != "local_affine":
            raise ValueError(
                f"sensor_scale={scale} needs arch='local_affine' (its network is trained through the sensor), "
                f"got arch={self.arch!r}"
            )
        share = self.val_fraction
        if isinstance(share, bool) or not isinstance(share, (int, float)) or not 0.0 <= share < 1.0:
            raise ValueError(f"val_fraction must be in [0, 1), got val_fraction={share!r}")
        object.__setattr__(self, "effects", tuple(check_effect_names(self.effects)))
        if Resolution.name in self.effects:
            raise ValueError(
                "effects: 'resolution' is not fitted after the network (it would blur twice); the network is trained "
                "through it: use sensor_scale (--sensor-scale): 'auto' finds it in the captures, or a scale such as 0.5"
            )
        check_seed(self.seed)

    @classmethod
    def recipe(cls, name: str = "fast", **overrides: Any) -> FitConfig:
        """The named recipe of :data:`RECIPES`, with ``overrides`` (``None`` values keep the recipe's)."""
        if name not in RECIPES:
            raise ValueError(f"recipe must be one of {tuple(RECIPES)}, got recipe={name!r}")
        values = {**RECIPES[name], **{key: value for key, value in overrides.items() if value is not None}}
        return cls(**values)

    def replace(self, **changes: Any) -> FitConfig:
        """This recipe with ``changes`` (``None`` values keep this recipe's), checked like a new one."""
        unknown = sorted(set(changes) - {item.name for item in fields(self)})
        if unknown:
            raise TypeError(f"FitConfig has no field(s) {unknown}; its fields: {[item.name for item in fields(self)]}")
        return replace(self, **{key: value for key, value in changes.items() if value is not None})

    def as_dict(self) -> dict[str, Any]:
        """Every value, ``effects`` as a list (JSON's)."""
        values = asdict(self)
        values["effects"] = list(self.effects)
        return values

    def training_dict(self) -> dict[str, Any]:
        """The network's training values (:data:`~camdegrade._recipes.TRAINING_FIELDS`): what a profile records as
        ``fitted['recipe']`` and a checkpoint must match to be resumed."""
        return {name: getattr(self, name) for name in TRAINING_FIELDS}


def resolve_recipe(recipe: str | FitConfig) -> FitConfig:
    """``recipe``: a name of ``RECIPES`` or a :class:`FitConfig`."""
    if isinstance(recipe, FitConfig):
        return recipe
    if not isinstance(recipe, str):
        raise TypeError(f"recipe must be a recipe name {tuple(RECIPES)} or a FitConfig, got {type(recipe).__name__}")
    return FitConfig.recipe(recipe)


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
    state = _initial_state(network, optimizer, scheduler, generator, config, checkpoint, resume, fingerprint, start)
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
    network, optimizer, scheduler, generator, config, checkpoint, resume, fingerprint: str, start=None
) -> TrainingState:
    best_score, best_network = start if start is not None else (-math.inf, None)
    fresh = capture_state(
        network,
        optimizer,
        scheduler,
        generator,
        epoch=0,
        best_score=best_score,
        best_network=best_network,
        config=config.training_dict(),
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
    # A resume may change how long the fit runs, unless the schedule is laid out over its length (cosine).
    free = ("patience",) if config.schedule == "cosine" else ("epochs", "patience")
    recipe = {k: v for k, v in config.training_dict().items() if k not in free}
    saved = {k: v for k, v in state.config.items() if k not in free}
    if set(saved) != set(recipe):
        raise ValueError(
            f"checkpoint {str(checkpoint)!r} was written by another camdegrade version (its recipe has the fields "
            f"{sorted(saved)}); start a new fit without resume"
        )
    if recipe != saved:
        raise ValueError(f"checkpoint {str(checkpoint)!r} was written with a different recipe: {saved}, now {recipe}")
    if state.data != fingerprint:
        raise CamdegradeError(
            f"checkpoint {str(checkpoint)!r} was written for other training pairs or sensor (fingerprint "
            f"{state.data or 'none recorded'}, these pairs give {fingerprint}); resume with the same pairs, or start "
            "a new fit without resume"
        )
    network.load_state_dict(state.network)
    optimizer.load_state_dict(state.optimizer)
    scheduler.load_state_dict(state.scheduler)
    generator.set_state(state.generator)
    return state


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
    computes it natively (:func:`camdegrade.inference.native_bfloat16`); float32 otherwise."""
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
