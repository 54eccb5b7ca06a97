"""Shared plumbing of the kernels: dtype handling, shape checks and per-sample parameter broadcasting."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch
from torch import Tensor

from camdegrade._support.pixels import bytes_to_unit, unit_to_bytes

ParamLike = Tensor | float | int | Sequence[float]

_FLOAT_DTYPES = (torch.float16, torch.bfloat16, torch.float32, torch.float64)


def check_image(image: Tensor, name: str = "image") -> None:
    """Raise a clear error unless ``image`` is a ``[..., 3, H, W]`` uint8 or float tensor."""
    if not isinstance(image, Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(image).__name__}")
    if image.ndim < 3 or image.shape[-3] != 3:
        raise ValueError(f"{name} must have shape [..., 3, H, W], got shape {tuple(image.shape)}")
    if image.dtype != torch.uint8 and image.dtype not in _FLOAT_DTYPES:
        raise TypeError(f"{name} must be uint8 or a floating-point tensor, got dtype {image.dtype}")


def compute_dtype(image: Tensor) -> torch.dtype:
    """float64 stays float64; every other dtype is computed in float32."""
    return torch.float64 if image.dtype == torch.float64 else torch.float32


def to_float(image: Tensor) -> Tensor:
    """``image`` as a float tensor in [0, 1] (a new tensor unless it already is float32/float64)."""
    check_image(image)
    return bytes_to_unit(image) if image.dtype == torch.uint8 else image.to(compute_dtype(image))


def restore(result: Tensor, like: Tensor) -> Tensor:
    """Cast a float result back to ``like``'s dtype (uint8: scaled, rounded and clamped)."""
    return unit_to_bytes(result) if like.dtype == torch.uint8 else result.to(like.dtype)


def apply_float(image: Tensor, fn: Callable[[Tensor], Tensor]) -> Tensor:
    """Run ``fn`` on a float copy of ``image`` and restore the input's dtype (the input is never modified)."""
    return restore(fn(to_float(image)), image)


def per_sample(value: ParamLike, image: Tensor, name: str, event_shape: tuple[int, ...] = ()) -> Tensor:
    """``value`` as a float tensor of shape ``(*lead, *event_shape)`` aligned with ``image``'s leading dims.

    A parameter may be a Python number, a 0-d tensor, or a tensor whose first dims index the image batch
    from the left (``(N,)`` for an image ``(N, 3, H, W)``; ``(N, T)`` for ``(N, T, 3, H, W)``), followed by
    ``event_shape``.
    Missing trailing batch dims are added as size 1, so the result broadcasts against ``image.shape[:-3]``.
    """
    batch_shape = tuple(image.shape[:-3])
    tensor = torch.as_tensor(value, dtype=compute_dtype(image), device=image.device)
    n_event = len(event_shape)
    if tensor.ndim < n_event or tuple(tensor.shape[tensor.ndim - n_event :]) != event_shape:
        raise ValueError(
            f"{name} must have trailing shape {event_shape} (one value per sample), got shape {tuple(tensor.shape)}"
        )
    lead = tuple(tensor.shape[: tensor.ndim - n_event])
    compatible = len(lead) <= len(batch_shape) and all(
        size in (1, batch) for size, batch in zip(lead, batch_shape, strict=False)
    )
    if not compatible:
        raise ValueError(
            f"{name} must be a scalar or have leading shape matching the image batch shape {batch_shape}, "
            f"got shape {tuple(tensor.shape)}"
        )
    return tensor.reshape(lead + (1,) * (len(batch_shape) - len(lead)) + event_shape)


def flat_param(value: ParamLike, image: Tensor, name: str, event_shape: tuple[int, ...] = ()) -> Tensor:
    """Like :func:`per_sample`, expanded and flattened to ``(M, *event_shape)``, ``M = prod(batch shape)``."""
    batch_shape = tuple(image.shape[:-3])
    tensor = per_sample(value, image, name, event_shape)
    return tensor.expand(batch_shape + event_shape).reshape((-1, *event_shape))


def as_channel_view(param: Tensor) -> Tensor:
    """A per-sample scalar ``(*lead)`` viewed as ``(*lead, 1, 1, 1)`` to broadcast over ``[3, H, W]``."""
    return param[..., None, None, None]


def one_plane_at_a_time(transform: Callable[..., Tensor], *planes: Tensor) -> Tensor:
    """``transform`` of each ``(1, ...)`` slice of ``planes`` along the first dim (several tensors: sliced alike,
    as long as one another), concatenated, on a CPU; elsewhere of the whole batch at once. For FFTs: on a CPU a
    batched transform may round differently from a single one (MKL's AVX-512 kernels do, by up to 4e-7), and an
    image must get the same bytes alone as in any batch, which one at a time also costs less (110 against 158 ms for
    64 planes of 224², one thread). On a GPU one at a time costs about 50 times as much (12 against 0.22 ms, an
    H200) and cuFFT's batched plans round differently from single ones too: there an image's last bits may depend
    on its batch."""
    if planes[0].device.type != "cpu":
        return transform(*planes)
    return torch.cat([transform(*slices) for slices in zip(*(plane.split(1) for plane in planes), strict=True)])
