"""Where this process stands in a ``torch.distributed`` job (``torchrun``); a single process outside one."""

from __future__ import annotations

import torch.distributed as dist


def is_distributed() -> bool:
    """Whether this process is part of an initialised process group."""
    return dist.is_available() and dist.is_initialized()


def rank_and_world_size() -> tuple[int, int]:
    """``(rank, world size)`` of the initialised process group, or ``(0, 1)``."""
    if is_distributed():
        return dist.get_rank(), dist.get_world_size()
    return 0, 1


def is_main_process() -> bool:
    return rank_and_world_size()[0] == 0
