"""A bounded cache of what :meth:`~camdegrade.profile.CameraProfile.simulate` computes again and again: a fit's steps
and a diagnosis simulate the same clean images with one network and a few effect chains, many times over (the texture,
noise-reduction and response steps each simulate the training and validation pairs before and after their stage,
sampled and deterministic).

Keys say what the output depends on and nothing else: the network's or the profile's content (a digest of every
tensor and every stage's name and settings, so an edit in place or a copy with the same values keys alike) and the
clean image's identity (the tensor and its in-place version; an entry goes when its clean image is freed, so an
identity is never reused while it is cached, and nothing outlives the pairs of a fit). A hit returns a copy of the
very tensor the first call computed, so results are the same bytes as without the cache.
"""

from __future__ import annotations

import hashlib
import threading
import weakref
from collections import OrderedDict
from typing import Any

import torch
from torch import Tensor, nn

__all__ = ["MAX_BYTES", "OUTPUTS", "OutputCache", "ProfileKeys", "content_key", "image_key"]

#: Bytes of outputs kept, the most recently used last: a City100 fit's 24 frames of 840×600 through the network and
#: three chains come to about 0.6 GB, of which the repeated ones fit here.
MAX_BYTES = 384 * 2**20


def content_key(module: nn.Module, extra: Any = ()) -> str:
    """A digest of ``module``'s tensors (names, dtypes, shapes and bytes) and ``extra`` (e.g. its stages' names and
    settings): equal for modules that compute the same thing."""
    digest = hashlib.blake2b(repr(extra).encode(), digest_size=16)
    for name, tensor in module.state_dict().items():
        value = tensor.detach().cpu().contiguous()
        digest.update(f"{name}:{value.dtype}:{tuple(value.shape)}".encode())
        digest.update(value.reshape(-1).view(torch.uint8).numpy().tobytes())
    return digest.hexdigest()


def image_key(image: Tensor) -> tuple:
    """The identity of ``image`` while it is unchanged (the cache holds the tensor, so its ``id`` stays its own)."""
    return (id(image), image._version, image.data_ptr(), tuple(image.shape), image.dtype)


class OutputCache:
    """Outputs by key, at most :data:`MAX_BYTES`, thread-safe; an entry is dropped when the clean image its key
    names is freed."""

    def __init__(self, max_bytes: int = MAX_BYTES) -> None:
        self.max_bytes = max_bytes
        self._entries: OrderedDict[tuple, tuple[weakref.ref, Tensor]] = OrderedDict()
        self._bytes = 0
        self._lock = threading.RLock()  # a freed image's callback may run while this thread holds it

    def get(self, key: tuple) -> Tensor | None:
        with self._lock:
            entry = self._entries.get(key)
            if entry is None:
                return None
            self._entries.move_to_end(key)
            return entry[1].clone()

    def put(self, key: tuple, image: Tensor, output: Tensor) -> None:
        size = output.numel() * output.element_size()
        if size > self.max_bytes:
            return
        with self._lock:
            if key in self._entries:
                return
            self._entries[key] = (weakref.ref(image, lambda _: self._discard(key)), output.clone())
            self._bytes += size
            while self._bytes > self.max_bytes:
                self._discard(next(iter(self._entries)))

    def _discard(self, key: tuple) -> None:
        with self._lock:
            entry = self._entries.pop(key, None)
            if entry is not None:
                self._bytes -= entry[1].numel() * entry[1].element_size()

    def __len__(self) -> int:
        return len(self._entries)

    def clear(self) -> None:
        with self._lock:
            self._entries.clear()
            self._bytes = 0


class ProfileKeys:
    """The cache keys of one profile's network and of the whole profile (a
    :class:`~camdegrade.profile.CameraProfile`: its ``network`` and ``effects``), computed when first needed."""

    def __init__(self, profile: Any) -> None:
        self.profile = profile
        self._network: str | None = None
        self._whole: str | None = None

    def network(self) -> str:
        network = self.profile.network
        if self._network is None and network is not None:
            self._network = content_key(network, (type(network).__name__, network.config()))
        return self._network or ""

    def whole(self) -> str:
        if self._whole is None:
            stages = [(effect.name, effect.config()) for effect in self.profile.effects]
            self._whole = self.network() + content_key(self.profile.effects, stages)
        return self._whole


OUTPUTS = OutputCache()
