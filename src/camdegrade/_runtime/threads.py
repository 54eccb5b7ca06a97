"""Running a block with a given number of torch CPU threads."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

import torch

#: The most torch CPU threads a command takes: more than a few per core only slows torch down, and a count in the
#: tens of thousands makes OpenMP fail to allocate its pool (a crash, not an error).
MAX_THREADS = max(64, 4 * (os.cpu_count() or 1))


@contextlib.contextmanager
def torch_threads(threads: int | None) -> Iterator[None]:
    """Run the block with ``threads`` torch threads (unchanged when None), then restore the previous count."""
    if threads is not None and (
        isinstance(threads, bool) or not isinstance(threads, int) or not 1 <= threads <= MAX_THREADS
    ):
        raise ValueError(f"threads must be an integer from 1 to {MAX_THREADS} or None, got threads={threads!r}")
    previous = torch.get_num_threads()
    if threads is not None:
        torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(previous)
