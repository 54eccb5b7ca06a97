"""Codec kernel: a real JPEG round trip through libjpeg (via Pillow) on the CPU."""

from __future__ import annotations

import io

import numpy as np
import torch
from PIL import Image
from torch import Tensor

from camdegrade._support.pixels import bytes_to_unit, unit_to_bytes
from camdegrade.functional._utils import ParamLike, check_image, compute_dtype, flat_param, restore, to_float

__all__ = ["check_quality", "jpeg_image"]


def check_quality(quality: Tensor) -> None:
    """Raise unless every value is an integer from 1 to 100."""
    bad = (quality < 1) | (quality > 100) | (quality != quality.round())
    if bool(bad.any()):
        value = quality[bad].flatten()[0].item()
        shown = int(value) if float(value).is_integer() else value
        raise ValueError(f"quality must be an integer from 1 to 100, got quality={shown}")


def _round_trip(plane: np.ndarray, quality: int) -> np.ndarray:
    buffer = io.BytesIO()
    # 4:2:0 chroma subsampling and the standard tables: what webcams and phones write.
    Image.fromarray(plane).save(buffer, format="JPEG", quality=quality, subsampling=2)
    buffer.seek(0)
    with Image.open(buffer) as decoded:
        return np.asarray(decoded.convert("RGB"))


def jpeg_image(image: Tensor, quality: ParamLike) -> Tensor:
    """Encode and decode each image as JPEG at ``quality`` (an integer 1–100, scalar or per-sample ``(N,)``).

    Float input is quantised to 8 bits first, as a camera's encoder does. The codec is libjpeg (through
    Pillow) on the CPU, which is deterministic; the result returns to the input's device and dtype.

    Examples:
        >>> image = torch.zeros(2, 3, 16, 16, dtype=torch.uint8)
        >>> jpeg_image(image, torch.tensor([10, 90])).shape
        torch.Size([2, 3, 16, 16])
    """
    check_image(image)
    qualities = flat_param(quality, image, "quality")
    check_quality(qualities)
    if image.numel() == 0:
        return image.clone()
    as_bytes = image if image.dtype == torch.uint8 else unit_to_bytes(to_float(image))
    planes = as_bytes.detach().cpu().reshape(-1, *image.shape[-3:]).permute(0, 2, 3, 1).numpy()
    decoded = [_round_trip(np.ascontiguousarray(plane), int(q)) for plane, q in zip(planes, qualities.tolist())]
    result = torch.from_numpy(np.stack(decoded)).permute(0, 3, 1, 2).reshape(image.shape).to(image.device)
    return result if image.dtype == torch.uint8 else restore(bytes_to_unit(result).to(compute_dtype(image)), image)
