"""Cache keys for values derived from tensors: they change whenever a tensor is replaced or modified in place."""

from __future__ import annotations

from collections.abc import Iterable

from torch import Tensor


def tensors_fingerprint(tensors: Iterable[Tensor]) -> tuple[int, ...]:
    """``(identity, in-place version, storage address)`` of every tensor, flattened: equal only while none of the
    tensors was swapped for another, edited in place (``_version`` counts that) or moved to new storage."""
    return tuple(part for t in tensors for part in (id(t), t._version, t.data_ptr()))
