"""The two-sample fit's checkpoint: everything needed to continue it to the same bytes, as one safetensors file
(tensors, and JSON metadata under one key; never a pickle)."""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Protocol

import torch
from torch import Tensor

from camdegrade.errors import CamdegradeError
from camdegrade.fitting.network.checkpoint import read_tensor_file, write_tensor_file

__all__ = ["TwoSampleState", "load_state", "save_state"]

STATE_KEY = "camdegrade_two_sample"
#: The state dicts and optimizers a checkpoint holds, by the prefix of their tensors' keys.
MODULES = ("stage", "average", "critic")
OPTIMIZERS = ("stage_optimizer", "critic_optimizer")


class Game(Protocol):
    """What a checkpoint reads and sets of the running fit (the trainer's game): its modules and optimizers by the
    names in :data:`MODULES` and :data:`OPTIMIZERS`, its generator, step and history, and what it was started with."""

    options: Any
    steps: int
    seed: int
    step: int
    history: list[dict[str, float]]
    generator: torch.Generator


@dataclass
class TwoSampleState:
    """A two-sample game after ``step`` steps: tensors by key, and what must match for a resume."""

    tensors: dict[str, Tensor]
    step: int
    steps: int
    seed: int
    options: dict[str, Any]
    fingerprint: str
    param_groups: dict[str, list[dict[str, Any]]] = field(default_factory=dict)
    history: list[dict[str, float]] = field(default_factory=list)

    @classmethod
    def capture(cls, game: Game, fingerprint: str) -> TwoSampleState:
        tensors: dict[str, Tensor] = {"generator": game.generator.get_state()}
        for name in MODULES:
            tensors.update({f"{name}.{key}": value for key, value in getattr(game, name).state_dict().items()})
        groups = {}
        for name in OPTIMIZERS:
            saved = getattr(game, name).state_dict()
            for index, slots in saved["state"].items():
                tensors.update({f"{name}.{index}.{slot}": value for slot, value in slots.items()})
            groups[name] = saved["param_groups"]
        return cls(
            tensors={key: value.detach().cpu().contiguous().clone() for key, value in tensors.items()},
            step=game.step,
            steps=game.steps,
            seed=game.seed,
            options=asdict(game.options),
            fingerprint=fingerprint,
            param_groups=groups,
            history=list(game.history),
        )

    def check_matches(self, game: Game, fingerprint: str, path: str | os.PathLike[str]) -> None:
        """Raise ``ValueError`` naming the first of options, seed, steps and data that differs from ``game``'s."""
        now = {"options": asdict(game.options), "seed": game.seed, "steps": game.steps, "data": fingerprint}
        saved = {"options": self.options, "seed": self.seed, "steps": self.steps, "data": self.fingerprint}
        for key, value in now.items():
            if json.loads(json.dumps(value)) != saved[key]:
                raise ValueError(
                    f"checkpoint {str(path)!r} was written with other {key} ({saved[key]}, now {value}); resume with "
                    "the same ones, or start a new fit without resume"
                )

    def restore(self, game: Game) -> None:
        """Set ``game``'s modules, optimizers, generator, step and history to this state."""
        for name in MODULES:
            prefix = f"{name}."
            module = getattr(game, name)
            module.load_state_dict({k[len(prefix) :]: v for k, v in self.tensors.items() if k.startswith(prefix)})
        for name in OPTIMIZERS:
            slots: dict[int, dict[str, Tensor]] = {}
            for key, value in self.tensors.items():
                if key.startswith(f"{name}."):
                    _, index, slot = key.split(".", 2)
                    slots.setdefault(int(index), {})[slot] = value
            getattr(game, name).load_state_dict({"state": slots, "param_groups": self.param_groups[name]})
        game.generator.set_state(self.tensors["generator"])
        game.step, game.history = self.step, list(self.history)


def save_state(state: TwoSampleState, path: str | os.PathLike[str]) -> Path:
    """Write ``state`` to ``path`` atomically (an interrupted write never replaces a good checkpoint)."""
    metadata = {
        "step": state.step,
        "steps": state.steps,
        "seed": state.seed,
        "options": state.options,
        "fingerprint": state.fingerprint,
        "param_groups": state.param_groups,
        "history": state.history,
    }
    return write_tensor_file(path, state.tensors, STATE_KEY, metadata)


def load_state(path: str | os.PathLike[str]) -> TwoSampleState:
    """Read a checkpoint written by :func:`save_state`; a ``CamdegradeError`` naming the file for anything else."""
    raw, tensors = read_tensor_file(path)
    try:
        metadata = json.loads(raw[STATE_KEY])
        return TwoSampleState(
            tensors=tensors,
            step=int(metadata["step"]),
            steps=int(metadata["steps"]),
            seed=int(metadata["seed"]),
            options=dict(metadata["options"]),
            fingerprint=str(metadata["fingerprint"]),
            param_groups=dict(metadata["param_groups"]),
            history=list(metadata["history"]),
        )
    except (KeyError, TypeError, ValueError) as error:
        raise CamdegradeError(
            f"{str(path)!r} is not a two-sample checkpoint of this camdegrade ({type(error).__name__}: {error}); "
            "delete it and fit without resume"
        ) from None
