"""Large standard-normal fields, drawn on several threads with values that do not depend on the thread count."""

from __future__ import annotations

import concurrent.futures
import math
import os
import threading
from collections.abc import Sequence

import torch
from torch import Tensor

#: Fields of at least ``MIN_BLOCKS`` blocks are drawn block by block, each block from its own generator seeded from
#: the caller's. torch's CPU generator is sequential (one Mersenne Twister); blocks let several threads share the
#: work, and the values depend only on the caller's generator and the field's size, never on the number of threads.
BLOCK = 1 << 16
#: Below this many blocks (about two 224² RGB images) a field is one ``torch.randn`` call: handing blocks to another
#: thread costs more than it saves there, as torch's own worker threads are still spinning after the previous op.
MIN_BLOCKS = 8

_POOL_LOCK = threading.Lock()
_pool: tuple[int, int, concurrent.futures.ThreadPoolExecutor] | None = None  # (pid, workers, executor)


def standard_normal(shape: Sequence[int], generator: torch.Generator | None = None) -> Tensor:
    """A float32 CPU tensor of independent N(0, 1) draws, reproducible from ``generator`` (or the global RNG).

    Large fields use as many threads as ``torch.get_num_threads()`` allows; a small one is one ``torch.randn`` call.
    """
    count = math.prod(shape)
    blocks = -(-count // BLOCK)
    if blocks < MIN_BLOCKS:
        return torch.randn(tuple(shape), generator=generator)
    seeds = torch.randint(0, 2**62, (blocks,), generator=generator).tolist()
    field = torch.empty(count)

    def fill(indices: range) -> None:
        for index in indices:
            block_generator = torch.Generator().manual_seed(seeds[index])
            field[index * BLOCK : (index + 1) * BLOCK].normal_(generator=block_generator)

    threads = min(torch.get_num_threads(), blocks)
    if threads == 1:
        fill(range(blocks))
    else:
        helpers = _helpers(threads - 1)
        pending = [helpers.submit(fill, range(start, blocks, threads)) for start in range(1, threads)]
        fill(range(0, blocks, threads))
        for future in pending:
            future.result()
    return field.view(tuple(shape))


def _helpers(workers: int) -> concurrent.futures.ThreadPoolExecutor:
    """A process-wide pool of at least ``workers`` threads (a fresh one in a forked child, whose copy has none)."""
    global _pool
    with _POOL_LOCK:
        if _pool is None or _pool[0] != os.getpid() or _pool[1] < workers:
            if _pool is not None and _pool[0] == os.getpid():
                _pool[2].shutdown(wait=False)
            _pool = (os.getpid(), workers, concurrent.futures.ThreadPoolExecutor(workers, "camdegrade-rng"))
        return _pool[2]
