"""8-bit pixels and unit floats: the one place that maps ``0…255`` to ``[0, 1]`` and back."""

from __future__ import annotations

import torch
from torch import Tensor


def bytes_to_unit(image: Tensor) -> Tensor:
    """uint8 values as float32 in [0, 1] (``value / 255``), in a new tensor."""
    return image.to(torch.float32).div_(255.0)


def unit_to_bytes(image: Tensor, *, overwrite: bool = False) -> Tensor:
    """Floats in [0, 1] as uint8 (scaled by 255, rounded half to even, clamped); ``overwrite`` lets it reuse
    ``image`` for the scaling."""
    scaled = image.mul_(255.0) if overwrite else image.mul(255.0)
    # float → uint8 has no vectorised CPU kernel; through int32 (exact for these integers) is several times faster.
    return scaled.round_().clamp_(0, 255).to(torch.int32).to(torch.uint8)


def as_unit(image: Tensor, *, clamp: bool = False) -> Tensor:
    """An image as float32 in [0, 1]: uint8 read as ``value / 255`` (a new tensor), floats converted to float32
    (the tensor itself when it already is float32 and ``clamp`` is off; ``clamp`` clamps to [0, 1] in a copy)."""
    if image.dtype == torch.uint8:
        return bytes_to_unit(image)
    unit = image.to(torch.float32)
    return unit.clamp(0.0, 1.0) if clamp else unit
