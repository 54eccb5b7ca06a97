"""Stable per-item randomness: one key per (seed, epoch, item, stream), whatever process computes it.

Keys come from :func:`camdegrade._support.seeds.derive_seed` (the package's one seed scheme), so every worker and every
rank derives the same key, decision and ``torch.Generator`` for the same item.
"""

from __future__ import annotations

import torch

from camdegrade._support.checks import check_int
from camdegrade._support.seeds import derive_seed, derived_generator

#: Stream numbers: the keep/degrade decision and the degradation's own random values never share draws.
DECISION_STREAM = 1
PARAMS_STREAM = 2

#: The public name of the key function (``camdegrade.data.stable_key``).
stable_key = derive_seed
#: The largest epoch: :class:`SharedEpoch` holds it in an int64.
MAX_EPOCH = 2**63 - 1


def check_epoch(epoch: object) -> int:
    """``epoch`` itself when it is an int from 0 to :data:`MAX_EPOCH`, else a ``TypeError``/``ValueError`` naming it."""
    return check_int("epoch", epoch, minimum=0, maximum=MAX_EPOCH)


def item_uniform(seed: int, epoch: int, index: int) -> float:
    """The uniform number in ``[0, 1)`` that decides whether item ``index`` is degraded in ``epoch``."""
    return (derive_seed(seed, epoch, index, DECISION_STREAM) >> 11) * 2.0**-53


def item_generator(seed: int, epoch: int, index: int) -> torch.Generator:
    """The CPU generator that draws the degradation of item ``index`` in ``epoch`` (noise, codec values, ...)."""
    return derived_generator(seed, epoch, index, PARAMS_STREAM)


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
        self._value.fill_(check_epoch(epoch))
