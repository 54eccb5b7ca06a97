"""Running a block with a given number of torch CPU threads."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

import torch

#: The most torch CPU threads a command takes: more than a few per core only slows torch down, and a count in the
#: tens of thousands makes OpenMP fail to allocate its pool (a crash, not an error).
MAX_THREADS = max(64, 4 * (os.cpu_count() or 1))
T = TypeVar("T")


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


def side_by_side(calls: Sequence[Callable[[], T]]) -> list[T]:
    """Each call's result, in order. With two or more torch threads, the calls run side by side on that many worker
    threads (at most one per call) of one torch thread each: small operations, such as a critic's on 32² patches,
    keep two cores busier this way than each split over two threads. With one torch thread, one after the other.
    Each call draws its randomness from its own generators, and gives the same bytes side by side as alone with one
    torch thread."""
    workers = min(len(calls), torch.get_num_threads())
    if workers < 2:
        return [call() for call in calls]

    def alone(call: Callable[[], T]) -> T:
        torch.set_num_threads(1)  # this worker thread's own count (OpenMP keeps one per thread)
        return call()

    with ThreadPoolExecutor(workers) as pool:
        return list(pool.map(alone, calls))
