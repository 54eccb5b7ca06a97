"""Image reading and writing. The only place camdegrade touches image files."""

from __future__ import annotations

import os
import struct
import warnings
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO

import numpy as np
import torch
from PIL import ExifTags, Image, ImageOps
from torch import Tensor

from camdegrade._files import atomic_path
from camdegrade._pixels import as_unit, unit_to_bytes
from camdegrade.errors import ImageError

#: File extensions read as images (compared case-insensitively).
_ORIENTATION_TAG = ExifTags.Base.Orientation
_TRANSPOSED_ORIENTATIONS = frozenset({5, 6, 7, 8})  # EXIF orientations that swap width and height
IMAGE_EXTENSIONS: frozenset[str] = frozenset({".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp"})
#: The most pixels (width × height) camdegrade decodes from one image file. Larger headers are refused before
#: decoding: a few kilobytes of PNG can claim 12000×12000 pixels. Pillow's own limit (``PIL.Image.MAX_IMAGE_PIXELS``,
#: about 8.9e7 by default) applies too, as an error rather than its warning; this cap still holds where a program
#: switched Pillow's off (``Image.MAX_IMAGE_PIXELS = None``).
MAX_PIXELS = 120_000_000
#: What Pillow raises for unreadable, truncated or malformed files (struct.error and IndexError from some plugins).
_DECODER_ERRORS = (OSError, SyntaxError, ValueError, EOFError, struct.error, IndexError)


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
    """Read an image file as a uint8 tensor ``(3, H, W)`` (RGB, EXIF orientation applied).

    Refused with an :class:`~camdegrade.errors.ImageError` naming the file, before anything large is decoded:
    anything but a regular file, images of more than :data:`MAX_PIXELS` pixels (or Pillow's own limit), images
    with several frames (animations, multi-page files) and truncated files (a PNG missing rows included).
    """
    path = Path(path)
    try:
        with _open(path) as image:
            _check_still(image, path)
            if image.format == "PNG":
                _check_png_complete(path, *image.size)
            image.load()
            rgb = to_rgb(image, source=str(path))
    except ImageError:
        raise
    except _DECODER_ERRORS as error:  # unreadable, truncated or malformed data
        raise ImageError(f"cannot read image {str(path)!r}: {error or type(error).__name__}") from error
    return torch.from_numpy(np.array(rgb, dtype=np.uint8)).permute(2, 0, 1).contiguous()


def read_image_size(path: str | os.PathLike[str]) -> tuple[int, int]:
    """``(height, width)`` of an image file after EXIF orientation, from its header only (no full decode).

    Raises the :class:`~camdegrade.errors.ImageError` :func:`read_image` raises for files it refuses from their
    header (not a regular file, too many pixels, several frames)."""
    path = Path(path)
    try:
        with _open(path) as image:
            _check_still(image, path)
            width, height = image.size
            # A PNG's EXIF may sit after the pixel data; asking for it would decode the whole image.
            has_exif = image.format != "PNG" or "exif" in image.info
            orientation = image.getexif().get(_ORIENTATION_TAG, 1) if has_exif else 1
    except ImageError:
        raise
    except _DECODER_ERRORS as error:
        raise ImageError(f"cannot read image {str(path)!r}: {error or type(error).__name__}") from error
    return (width, height) if orientation in _TRANSPOSED_ORIENTATIONS else (height, width)


def _check_regular_file(path: Path) -> None:
    """Raise :class:`ImageError` unless ``path`` is a regular file (a FIFO would block a reader, a device never
    ends), naming a file met on the way (``file.png/x.png``)."""
    if path.is_file():
        return
    for ancestor in path.parents:
        if ancestor.exists():
            if not ancestor.is_dir():
                raise ImageError(f"cannot read image {str(path)!r}: {str(ancestor)!r} is a file, not a folder")
            break
    if not path.exists():
        raise ImageError(f"cannot read image {str(path)!r}: no such file")
    kind = "a folder" if path.is_dir() else "not a regular file"
    raise ImageError(f"cannot read image {str(path)!r}: it is {kind}")


@contextmanager
def _open(path: Path) -> Iterator[Image.Image]:
    """``Image.open`` of a regular file whose header asks for at most :data:`MAX_PIXELS` (and Pillow's limit)."""
    _check_regular_file(path)
    with warnings.catch_warnings():
        # Pillow only warns between its limit and twice it; the size is checked just below, as an error.
        warnings.simplefilter("ignore", Image.DecompressionBombWarning)
        try:
            image = Image.open(path)
        except Image.DecompressionBombError as error:
            raise ImageError(f"image {str(path)!r} is too large to decode: {error}") from None
    with image:
        width, height = image.size
        limit, name = MAX_PIXELS, "camdegrade.io.MAX_PIXELS"
        if Image.MAX_IMAGE_PIXELS is not None and limit > Image.MAX_IMAGE_PIXELS:
            limit, name = int(Image.MAX_IMAGE_PIXELS), "PIL.Image.MAX_IMAGE_PIXELS"
        if width * height > limit:
            raise ImageError(
                f"image {str(path)!r} is {width}x{height} px ({width * height} pixels), more than camdegrade decodes "
                f"({name} ({limit})); refused before decoding, as a decompression bomb would be"
            )
        yield image


def _check_still(image: Image.Image, path: Path) -> None:
    """Refuse images of several frames: writing one frame of an animation would lose the rest silently. Phone
    JPEGs with an embedded preview (MPO) are one photo, frame 0."""
    frames = getattr(image, "n_frames", 1)
    if frames > 1 and image.format != "MPO":
        raise ImageError(
            f"image {str(path)!r} has {frames} frames (an animation or a multi-page file); camdegrade reads only "
            "still images: save the frame you want as an image file of its own"
        )


#: Channels of each PNG colour type (grey, RGB, palette, grey + alpha, RGBA).
_PNG_CHANNELS = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}
#: Adam7 interlacing passes: (x start, y start, x step, y step).
_ADAM7 = ((0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4), (0, 2, 2, 4), (1, 0, 2, 2), (0, 1, 1, 2))
_INFLATE_STEP = 1 << 20


def _check_png_complete(path: Path, width: int, height: int) -> None:
    """Raise :class:`ImageError` when a PNG's pixel data holds fewer bytes than its header needs.

    Pillow fills missing rows with black and reports nothing when the compressed stream ends early but cleanly.
    The IDAT chunks are inflated here in 1 MB steps and only counted, so the check needs no memory for pixels.
    """
    with path.open("rb") as handle:
        handle.read(8)  # the signature, checked by Pillow
        header = _png_header(handle)
        if header is None:
            return
        bits, colour, interlace = header
        bits_per_pixel = bits * _PNG_CHANNELS.get(colour, 4)
        passes = _ADAM7 if interlace else ((0, 0, 1, 1),)
        expected = 0
        for x0, y0, dx, dy in passes:
            columns, rows = -(-(width - x0) // dx), -(-(height - y0) // dy)
            if columns > 0 and rows > 0:
                expected += rows * (1 + -(-columns * bits_per_pixel // 8))
        found = _inflated_idat_bytes(handle, expected)
    if found < expected:
        if interlace:
            where = f"{found} of its {expected} bytes"
        else:
            where = f"{found // (1 + -(-width * bits_per_pixel // 8))} of {height} rows"
        raise ImageError(f"image {str(path)!r} is truncated: its pixel data ends after {where}")


def _png_header(handle: IO[bytes]) -> tuple[int, int, int] | None:
    length_and_kind = handle.read(8)
    if len(length_and_kind) < 8 or length_and_kind[4:] != b"IHDR":
        return None
    data = handle.read(13)
    handle.read(4)  # CRC
    return (data[8], data[9], data[12]) if len(data) == 13 else None


def _inflated_idat_bytes(handle: IO[bytes], enough: int) -> int:
    """How many bytes the IDAT chunks after ``handle``'s position inflate to (counting stops at ``enough``)."""
    inflater = zlib.decompressobj()
    total = 0
    while total < enough:
        head = handle.read(8)
        if len(head) < 8:
            break
        length, kind = struct.unpack(">I4s", head)
        if kind == b"IEND":
            break
        if kind != b"IDAT":
            handle.seek(length + 4, os.SEEK_CUR)
            continue
        data = handle.read(length)
        handle.read(4)
        try:
            while data and total < enough:
                total += len(inflater.decompress(data, _INFLATE_STEP))
                data = inflater.unconsumed_tail
        except zlib.error:
            break  # Pillow reports a broken stream itself
    return total


def write_image(image: Tensor, path: str | os.PathLike[str]) -> None:
    """Write a ``(3, H, W)`` uint8 or float-in-[0,1] tensor atomically; format from the suffix (JPEG at quality 95)."""
    path = Path(path)
    if image.ndim != 3 or image.shape[0] != 3:
        raise ValueError(f"image must have shape (3, H, W), got shape {tuple(image.shape)}")
    if image.dtype != torch.uint8:
        image = unit_to_bytes(as_unit(image.detach()))
    pil = Image.fromarray(image.permute(1, 2, 0).cpu().numpy())
    image_format = Image.registered_extensions().get(path.suffix.lower())
    if image_format is None:
        raise ValueError(f"path must end in an image extension such as .png or .jpg, got {str(path)!r}")
    options = {"quality": 95} if image_format == "JPEG" else {}
    with atomic_path(path) as temporary:
        pil.save(temporary, format=image_format, **options)
