"""Tiny map-style and iterable datasets for the data tests (importable by spawned processes and workers)."""

from __future__ import annotations

import hashlib
from typing import Any

import torch
from torch.utils.data import Dataset, IterableDataset, get_worker_info

SIZE = 16


def tiny_image(index: int, size: int = SIZE) -> torch.Tensor:
    """A deterministic uint8 image ``(3, size, size)`` for item ``index``."""
    generator = torch.Generator().manual_seed(1000 + index)
    return torch.randint(0, 256, (3, size, size), dtype=torch.uint8, generator=generator)


class TinyImages(Dataset):
    """``length`` items: ``(image, label)`` tuples, or dicts ``{"image", "index", "label"}`` with ``as_dict``."""

    def __init__(self, length: int, as_dict: bool = False, size: int = SIZE) -> None:
        self.length = length
        self.as_dict = as_dict
        self.size = size
        self.classes = ["a", "b", "c"]

    def __len__(self) -> int:
        return self.length

    def __getitem__(self, index: int) -> Any:
        if not 0 <= index < self.length:
            raise IndexError(index)
        image = tiny_image(index, self.size)
        if self.as_dict:
            return {"image": image, "index": index, "label": index % 3}
        return image, index % 3


class TinyStream(IterableDataset):
    """Items ``0 .. length-1`` as dicts, sharded round-robin over DataLoader workers."""

    def __init__(self, length: int) -> None:
        self.length = length

    def __iter__(self):
        info = get_worker_info()
        workers, worker_id = (1, 0) if info is None else (info.num_workers, info.id)
        for index in range(worker_id, self.length, workers):
            yield {"image": tiny_image(index), "index": index, "label": index % 3}


def digest(image: torch.Tensor) -> str:
    return hashlib.sha256(image.contiguous().numpy().tobytes()).hexdigest()[:16]
