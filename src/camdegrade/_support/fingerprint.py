"""Cache keys for values derived from tensors: they change whenever a tensor is replaced or modified in place."""

from __future__ import annotations

from collections.abc import Iterable, Iterator

from torch import Tensor, nn


def tensors_fingerprint(tensors: Iterable[Tensor]) -> tuple[int, ...]:
    """``(identity, in-place version, storage address)`` of every tensor, flattened: equal only while none of the
    tensors was swapped for another, edited in place (``_version`` counts that) or moved to new storage."""
    return tuple(part for t in tensors for part in (id(t), t._version, t.data_ptr()))


def module_tensors(module: nn.Module) -> Iterator[Tensor]:
    """Every parameter and buffer of ``module`` and its submodules (shared ones once per holder).

    A plain walk of ``_modules``: ``parameters()``/``buffers()`` build prefixed names and a memo on every call,
    which costs a measurable share of a single-image transform when it runs on each call.
    """
    yield from (t for t in module._parameters.values() if t is not None)
    yield from (t for t in module._buffers.values() if t is not None)
    for child in module._modules.values():
        if child is not None:
            yield from module_tensors(child)
