"""Helpers shared by the effect modules: buffers, batch shapes and parameter resolution."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from torch import Tensor

from camdegrade.effects.base import Effect


def scalar(value: float | Tensor) -> Tensor:
    """A 0-d float32 buffer value."""
    return torch.as_tensor(value, dtype=torch.float32).detach().clone().reshape(())


def vector(value: float | Sequence[float] | Tensor, size: int, name: str) -> Tensor:
    """A ``(size,)`` float32 buffer value; a scalar is repeated."""
    tensor = torch.as_tensor(value, dtype=torch.float32).detach().clone()
    if tensor.ndim == 0:
        tensor = tensor.expand(size).clone()
    if tensor.shape != (size,):
        raise ValueError(f"{name} must be a number or have shape ({size},), got shape {tuple(tensor.shape)}")
    return tensor


def batch_shape(shape: torch.Size | Sequence[int]) -> tuple[int, int, int, int]:
    """Validate ``shape = (N, 3, H, W)`` and return it as a tuple of ints."""
    dims = tuple(int(size) for size in shape)
    if len(dims) != 4 or dims[1] != 3:
        raise ValueError(f"shape must be (N, 3, H, W), got shape {dims}")
    return dims  # type: ignore[return-value]


def resolve_params(effect: Effect, image: Tensor, params: Mapping[str, Tensor] | None) -> dict[str, Tensor]:
    """``params`` moved to ``image``'s device; ``None`` draws fresh ones from torch's global RNG."""
    drawn = effect.make_params(image.shape) if params is None else params
    return {key: value.to(image.device) for key, value in drawn.items()}
