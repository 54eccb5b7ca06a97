"""Stable per-item randomness: one key per (seed, epoch, item, stream), whatever process computes it.

Python's ``hash()`` is salted per process and torch's global RNG differs in every DataLoader worker, so neither
can say which items are degraded. Keys here are mixed from integers with SplitMix64's finaliser, a fixed formula,
so every worker and every rank derives the same key, decision and ``torch.Generator`` for the same item.
"""

from __future__ import annotations

from typing import Any

import torch

_MASK = (1 << 64) - 1

#: Stream numbers: the keep/degrade decision and the degradation's own random values never share draws.
DECISION_STREAM = 1
PARAMS_STREAM = 2


def _mix64(value: int) -> int:
    """SplitMix64's finaliser: a bijection on 64-bit integers that spreads every input bit over the output."""
    value = (value + 0x9E3779B97F4A7C15) & _MASK
    value = ((value ^ (value >> 30)) * 0xBF58476D1CE4E5B9) & _MASK
    value = ((value ^ (value >> 27)) * 0x94D049BB133111EB) & _MASK
    return value ^ (value >> 31)


def stable_key(*parts: int) -> int:
    """A 64-bit key from integers (negative ones wrap modulo 2**64); equal parts give equal keys in any process."""
    key = 0
    for part in parts:
        key = _mix64(key ^ (part & _MASK))
    return key


def item_uniform(seed: int, epoch: int, index: int) -> float:
    """The uniform number in ``[0, 1)`` that decides whether item ``index`` is degraded in ``epoch``."""
    return (stable_key(seed, epoch, index, DECISION_STREAM) >> 11) * 2.0**-53


def item_generator(seed: int, epoch: int, index: int) -> torch.Generator:
    """The CPU generator that draws the degradation of item ``index`` in ``epoch`` (noise, codec values, ...)."""
    return torch.Generator().manual_seed(stable_key(seed, epoch, index, PARAMS_STREAM))


def check_int(name: str, value: Any, minimum: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise TypeError(f"{name} must be an int, got {name}={value!r} ({type(value).__name__})")
    if minimum is not None and value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {name}={value}")
    return value


class SharedEpoch:
    """An epoch counter that DataLoader workers read live, persistent workers included.

    The value sits in a one-element shared-memory tensor. Forked workers map the same memory; spawned workers
    receive a handle to it (torch's multiprocessing pickler shares tensors instead of copying them). So
    ``set_epoch`` in the main process reaches workers that were started before it was called.
    """

    def __init__(self, epoch: int = 0) -> None:
        self._value = torch.zeros((), dtype=torch.int64).share_memory_()
        self.set(epoch)

    def get(self) -> int:
        return int(self._value.item())

    def set(self, epoch: int) -> None:
        self._value.fill_(check_int("epoch", epoch, minimum=0))
