"""Image reading and writing. The only place camdegrade touches image files."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch
from PIL import ExifTags, Image, ImageOps
from torch import Tensor

from camdegrade._files import atomic_path
from camdegrade._pixels import as_unit, unit_to_bytes

#: File extensions read as images (compared case-insensitively).
_ORIENTATION_TAG = ExifTags.Base.Orientation
_TRANSPOSED_ORIENTATIONS = frozenset({5, 6, 7, 8})  # EXIF orientations that swap width and height
IMAGE_EXTENSIONS: frozenset[str] = frozenset({".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp"})


def is_image_path(path: str | os.PathLike[str]) -> bool:
    return Path(path).suffix.lower() in IMAGE_EXTENSIONS


def iter_images(folder: str | os.PathLike[str]) -> Iterator[Path]:
    """Image files under ``folder``, recursively, in sorted order (hidden files skipped)."""
    root = Path(folder)
    for path in sorted(root.rglob("*")):
        if (
            path.is_file()
            and is_image_path(path)
            and not any(part.startswith(".") for part in path.relative_to(root).parts)
        ):
            yield path


def to_rgb(image: Image.Image, *, source: str = "image") -> Image.Image:
    """Convert a PIL image of any common mode to 8-bit RGB, with EXIF orientation applied.

    Grayscale and palette images are expanded; 16-bit images are scaled to 8 bits; alpha is dropped (composited on
    nothing: the colour channels are kept as they are). Modes with no sensible RGB meaning (e.g. CMYK is fine,
    but 'F' float images are refused) raise a ``ValueError`` naming ``source``.
    """
    image = ImageOps.exif_transpose(image)
    mode = image.mode
    if mode == "RGB":
        return image
    if mode in ("I;16", "I;16B", "I;16L", "I"):
        array = np.asarray(image, dtype=np.float64)
        scale = 65535.0 if mode.startswith("I;16") or array.max() > 255 else 255.0
        gray = np.clip(np.round(array / scale * 255.0), 0, 255).astype(np.uint8)
        return Image.fromarray(gray, mode="L").convert("RGB")
    if mode in ("L", "LA", "P", "PA", "RGBA", "RGBX", "RGBa", "CMYK", "YCbCr", "LAB", "HSV", "1", "La"):
        return image.convert("RGB")
    raise ValueError(f"{source} has PIL mode {mode!r}, which camdegrade cannot convert to RGB; save it as 8-bit RGB")


def read_image(path: str | os.PathLike[str]) -> Tensor:
    """Read an image file as a uint8 tensor ``(3, H, W)`` (RGB, EXIF orientation applied)."""
    path = Path(path)
    try:
        with Image.open(path) as image:
            image.load()
            rgb = to_rgb(image, source=str(path))
    except (OSError, SyntaxError) as error:  # PIL raises these for unreadable/truncated files
        raise OSError(f"cannot read image {str(path)!r}: {error}") from error
    return torch.from_numpy(np.array(rgb, dtype=np.uint8)).permute(2, 0, 1).contiguous()


def read_image_size(path: str | os.PathLike[str]) -> tuple[int, int]:
    """``(height, width)`` of an image file after EXIF orientation, from its header only (no full decode)."""
    try:
        with Image.open(path) as image:
            width, height = image.size
            # A PNG's EXIF may sit after the pixel data; asking for it would decode the whole image.
            has_exif = image.format != "PNG" or "exif" in image.info
            orientation = image.getexif().get(_ORIENTATION_TAG, 1) if has_exif else 1
    except (OSError, SyntaxError, ValueError, Image.DecompressionBombError) as error:
        raise OSError(f"cannot read image {str(path)!r}: {error or type(error).__name__}") from error
    return (width, height) if orientation in _TRANSPOSED_ORIENTATIONS else (height, width)


def write_image(image: Tensor, path: str | os.PathLike[str]) -> None:
    """Write a ``(3, H, W)`` uint8 or float-in-[0,1] tensor atomically; format from the suffix (JPEG at quality 95)."""
    path = Path(path)
    if image.ndim != 3 or image.shape[0] != 3:
        raise ValueError(f"image must have shape (3, H, W), got shape {tuple(image.shape)}")
    if image.dtype != torch.uint8:
        image = unit_to_bytes(as_unit(image.detach()))
    pil = Image.fromarray(image.permute(1, 2, 0).cpu().numpy())
    path.parent.mkdir(parents=True, exist_ok=True)
    image_format = Image.registered_extensions().get(path.suffix.lower())
    if image_format is None:
        raise ValueError(f"path must end in an image extension such as .png or .jpg, got {str(path)!r}")
    options = {"quality": 95} if image_format == "JPEG" else {}
    with atomic_path(path) as temporary:
        pil.save(temporary, format=image_format, **options)
