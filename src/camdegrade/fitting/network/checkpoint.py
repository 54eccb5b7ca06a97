"""Training checkpoints as safetensors: network, optimizer, schedule, RNG and history, written atomically."""

from __future__ import annotations

import hashlib
import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from safetensors import SafetensorError, safe_open
from safetensors.torch import save_file
from torch import Tensor

from camdegrade._support.files import atomic_path
from camdegrade.errors import CamdegradeError
from camdegrade.pairs.pairset import ImagePair

__all__ = [
    "CHECKPOINT_KEY",
    "REQUIRED_KEYS",
    "TrainingState",
    "capture_state",
    "load_checkpoint",
    "read_tensor_file",
    "save_checkpoint",
    "write_tensor_file",
]

CHECKPOINT_KEY = "camdegrade_checkpoint"
#: Metadata keys every checkpoint holds (and the tensor ``generator``).
REQUIRED_KEYS = ("epoch", "best_score", "history", "config", "param_groups", "scheduler")


@dataclass
class TrainingState:
    """Everything needed to continue a fit exactly where it stopped (at an epoch boundary)."""

    network: dict[str, Tensor]
    optimizer: dict[str, Any]
    scheduler: dict[str, Any]
    generator: Tensor
    epoch: int
    best_score: float
    best_network: dict[str, Tensor] | None
    history: list[dict[str, Any]] = field(default_factory=list)
    config: dict[str, Any] = field(default_factory=dict)
    #: A fingerprint of the training and validation pairs (names, sizes, sampled pixels): a resume must use them.
    data: str = ""


def save_checkpoint(state: TrainingState, path: str | os.PathLike[str]) -> Path:
    """Write ``state`` to ``path`` (temp file + rename: an interrupted write never replaces a good checkpoint)."""
    tensors = {f"network.{k}": v for k, v in state.network.items()}
    if state.best_network is not None:
        tensors.update({f"best.{k}": v for k, v in state.best_network.items()})
    tensors["generator"] = state.generator
    for index, slots in state.optimizer["state"].items():
        tensors.update({f"optimizer.{index}.{name}": value for name, value in slots.items()})
    tensors = {k: v.detach().cpu().contiguous().clone() for k, v in tensors.items()}
    metadata = {
        "epoch": state.epoch,
        "best_score": state.best_score,
        "history": state.history,
        "config": state.config,
        "param_groups": state.optimizer["param_groups"],
        "scheduler": state.scheduler,
        "data": state.data,
    }
    return write_tensor_file(path, tensors, CHECKPOINT_KEY, metadata)


def write_tensor_file(path: str | os.PathLike[str], tensors: dict[str, Tensor], key: str, metadata: Any) -> Path:
    """``tensors`` and ``metadata`` (JSON under ``key``) written to ``path`` as safetensors, atomically: an
    interrupted write never replaces a good checkpoint."""
    with atomic_path(path) as temporary:
        save_file(tensors, str(temporary), metadata={key: json.dumps(metadata, sort_keys=True)})
    return Path(path)


def read_tensor_file(path: str | os.PathLike[str]) -> tuple[dict[str, str], dict[str, Tensor]]:
    """The string metadata and the tensors of a safetensors checkpoint (never unpickles); a ``CamdegradeError``
    naming the file when it cannot be read."""
    try:
        with safe_open(str(path), framework="pt", device="cpu") as handle:
            raw = handle.metadata() or {}
            tensors = {key: handle.get_tensor(key) for key in handle.keys()}  # noqa: SIM118
    except (SafetensorError, OSError) as error:
        raise CamdegradeError(f"cannot read checkpoint {str(path)!r}: {error}") from error
    return raw, tensors


def load_checkpoint(path: str | os.PathLike[str]) -> TrainingState:
    """Read a checkpoint written by :func:`save_checkpoint` (safetensors only; never unpickles)."""
    raw, tensors = read_tensor_file(path)
    if CHECKPOINT_KEY not in raw:
        raise CamdegradeError(f"{str(path)!r} is not a camdegrade training checkpoint")
    try:
        metadata = json.loads(raw[CHECKPOINT_KEY])
    except (json.JSONDecodeError, RecursionError) as error:
        raise CamdegradeError(
            f"checkpoint {str(path)!r} metadata is not valid JSON ({error}); delete it and fit without resume"
        ) from None
    if not isinstance(metadata, dict):
        raise CamdegradeError(f"{str(path)!r} is not a camdegrade training checkpoint (metadata is not an object)")
    for key in (*REQUIRED_KEYS, "generator"):
        if key not in (tensors if key == "generator" else metadata):
            raise CamdegradeError(
                f"checkpoint {str(path)!r} lacks {key!r} (damaged, or written by another version); "
                "delete it and fit without resume"
            )
    optimizer_state: dict[int, dict[str, Tensor]] = {}
    for key, value in tensors.items():
        if key.startswith("optimizer."):
            _, index, name = key.split(".", 2)
            optimizer_state.setdefault(int(index), {})[name] = value
    best = {k[len("best.") :]: v for k, v in tensors.items() if k.startswith("best.")}
    return TrainingState(
        network={k[len("network.") :]: v for k, v in tensors.items() if k.startswith("network.")},
        optimizer={"state": optimizer_state, "param_groups": metadata["param_groups"]},
        scheduler=metadata["scheduler"],
        generator=tensors["generator"],
        epoch=metadata["epoch"],
        best_score=metadata["best_score"],
        best_network=best or None,
        history=metadata["history"],
        config=metadata["config"],
        data=str(metadata.get("data", "")),
    )


def capture_state(
    network: torch.nn.Module,
    optimizer: torch.optim.Optimizer,
    scheduler: torch.optim.lr_scheduler.LRScheduler,
    generator: torch.Generator,
    **fields: Any,
) -> TrainingState:
    """Snapshot live training objects into a :class:`TrainingState`."""
    optimizer_state = optimizer.state_dict()
    return TrainingState(
        network={k: v.detach().clone() for k, v in network.state_dict().items()},
        optimizer={"state": optimizer_state["state"], "param_groups": optimizer_state["param_groups"]},
        scheduler=scheduler.state_dict(),
        generator=generator.get_state(),
        **fields,
    )


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


def initial_state(
    network, optimizer, scheduler, generator, config, checkpoint, resume, fingerprint: str, start=None
) -> TrainingState:
    """The training state a fit starts from: fresh (the network at ``start``'s best weights and score, when given),
    or with ``resume`` the checkpoint's, after checking that it was written for the same recipe (``config``, a
    :class:`~camdegrade.fitting.FitConfig`) and pairs (``fingerprint``: :func:`pairs_fingerprint`)."""
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
