"""Seeds derived one way: a run seed plus named streams, mixed into one 64-bit key with SplitMix64's finaliser.

Python's ``hash()`` is salted per process and torch's global RNG differs in every DataLoader worker, so neither can
say what an item, a worker or a simulated image should draw. A key here is a fixed formula of its parts (integers,
and stream names hashed with BLAKE2b), so every worker, rank and process derives the same key for the same parts,
and different streams of one run never share draws.

Examples:
    >>> derive_seed(0, "simulate", "a.png") == derive_seed(0, "simulate", "a.png")
    True
    >>> derive_seed(0, "simulate", "a.png") != derive_seed(0, "simulate", "b.png")
    True
"""

from __future__ import annotations

import hashlib

import torch

_MASK = (1 << 64) - 1


def _mix64(value: int) -> int:
    """SplitMix64's finaliser: a bijection on 64-bit integers that spreads every input bit over the output."""
    value = (value + 0x9E3779B97F4A7C15) & _MASK
    value = ((value ^ (value >> 30)) * 0xBF58476D1CE4E5B9) & _MASK
    value = ((value ^ (value >> 27)) * 0x94D049BB133111EB) & _MASK
    return value ^ (value >> 31)


def _as_int(part: int | str) -> int:
    if isinstance(part, str):
        return int.from_bytes(hashlib.blake2b(part.encode("utf-8"), digest_size=8).digest(), "little")
    return int(part)


def derive_seed(*parts: int | str) -> int:
    """A 64-bit seed from integers (negative ones wrap modulo 2**64) and stream names; equal parts give equal
    seeds in any process."""
    key = 0
    for part in parts:
        key = _mix64(key ^ (_as_int(part) & _MASK))
    return key


def derived_generator(*parts: int | str) -> torch.Generator:
    """A CPU ``torch.Generator`` seeded with :func:`derive_seed` of ``parts``."""
    return torch.Generator().manual_seed(derive_seed(*parts))
