"""8-bit pixels and unit floats: the one place that maps ``0…255`` to ``[0, 1]`` and back."""

from __future__ import annotations

import math

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


#: Float images may stray this far outside [0, 1] and are clamped: bicubic resizing of photos overshoots by about
#: 0.04. Values further out mean another scale (0..255, [-1, 1], normalised) and are refused.
UNIT_TOLERANCE = 0.1
#: What :func:`off_unit_scale` says of an image with NaN or infinite values.
NOT_FINITE = "NaN or infinite values"
#: How to bring the usual other scales to [0, 1], for error messages.
SCALE_HINT = "scale 0..255 images by 1/255 (or pass uint8) and map [-1, 1] images with (x + 1) / 2"


def off_unit_scale(image: Tensor) -> str | None:
    """What keeps float ``image`` from being a [0, 1] image (NaN or infinite values, or values further than
    :data:`UNIT_TOLERANCE` outside it), or ``None``. One ``aminmax`` pass (about 0.05 ms for a 224² image on one CPU
    thread, 15× cheaper than ``isfinite().all()``)."""
    low, high = torch.stack(torch.aminmax(image.detach())).tolist()  # NaN propagates to both
    if not (math.isfinite(low) and math.isfinite(high)):
        return NOT_FINITE
    if low < -UNIT_TOLERANCE or high > 1.0 + UNIT_TOLERANCE:
        return f"values in [{low:.4g}, {high:.4g}]"
    return None
