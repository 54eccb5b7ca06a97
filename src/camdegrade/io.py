"""Image reading and writing. The only place camdegrade touches image files."""

from __future__ import annotations

import os
import struct
import warnings
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

import numpy as np
import torch
from PIL import ExifTags, Image, ImageOps
from torch import Tensor

from camdegrade._support.files import atomic_path, folder_relation
from camdegrade._support.pixels import NOT_FINITE, SCALE_HINT, as_unit, off_unit_scale, unit_to_bytes
from camdegrade.errors import ImageError

__all__ = [
    "IMAGE_EXTENSIONS",
    "MAX_PIXELS",
    "input_images",
    "is_image_path",
    "iter_images",
    "read_image",
    "read_image_size",
    "to_rgb",
    "write_image",
]

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
    """Image files under ``folder``, recursively, in sorted order (hidden files and folders skipped; symbolic links
    to folders are not followed).

    Entries that cannot be read are yielded too, so that reading them names the problem instead of a batch leaving
    them out silently: an entry with an image extension that is not a regular file (a dangling symbolic link, a
    link loop, a FIFO) and a folder that cannot be listed (no permission)."""
    root = Path(folder)
    found: list[Path] = []
    unlisted: list[Path] = []

    def unreadable(error: OSError) -> None:  # a folder that exists but cannot be listed
        if error.filename is not None and Path(os.fsdecode(error.filename)).is_dir():
            unlisted.append(Path(os.fsdecode(error.filename)))

    # os.walk lists links to folders among the folders and does not enter them; dangling links and link loops are
    # listed among the files, as are FIFOs, sockets and devices.
    for current, folders, files in os.walk(root, onerror=unreadable):
        folders[:] = [name for name in folders if not name.startswith(".")]
        found += [Path(current, name) for name in files if not name.startswith(".") and is_image_path(name)]
    yield from sorted([*found, *unlisted])


def input_images(
    source: Path, output: Path, *, overwrite: bool, output_name: str, allow: str
) -> list[tuple[Path, Path]]:
    """``(image, name relative to the input)`` for a command that reads ``source`` (an image file or a folder,
    recursively) and writes into ``output``; refused before anything is read: an input that is neither, an output
    folder that is the input folder, and one inside it unless ``overwrite`` (whose images are then left out of
    the inputs, so a rerun never reads its own outputs). ``output_name`` and ``allow`` (how to pass
    ``overwrite``) are the caller's words for the messages."""
    if source.is_file():
        if not is_image_path(source):
            raise ValueError(f"input must be an image file or a folder of images, got {str(source)!r}")
        return [(source, Path(source.name))]
    if not source.is_dir():
        if source.exists():
            raise ValueError(f"input {str(source)!r} is not a regular file or folder (a device, FIFO or socket)")
        raise FileNotFoundError(f"input {str(source)!r} does not exist")
    if output.exists() and not output.is_dir():
        raise ValueError(f"{output_name} must be a folder when the input is a folder, got file {str(output)!r}")
    relation = folder_relation(source, output)
    if relation == "same":
        raise ValueError(
            f"{output_name} {str(output)!r} is the input folder: what is written would land among the images it is "
            "made from; choose another folder"
        )
    if relation == "inside" and not overwrite:
        raise ValueError(
            f"{output_name} {str(output)!r} is inside the input folder {str(source)!r}: a rerun would read what it "
            f"wrote as inputs; choose a folder outside it, or {allow} (it is then left out of the inputs)"
        )
    skipped = output.resolve() if relation == "inside" else None
    found = [
        (path, path.relative_to(source))
        for path in iter_images(source)
        if skipped is None or not path.resolve().is_relative_to(skipped)
    ]
    if not found:
        raise ValueError(f"input folder {str(source)!r} holds no images (looked for .png, .jpg, ...)")
    return found


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
            # A PNG's EXIF may sit after the pixel data, where Pillow finds it only by decoding the whole image:
            # its chunks are walked instead (as read_image, which decodes, applies that EXIF too).
            if image.format == "PNG" and "exif" not in image.info:
                orientation = _png_late_orientation(path)
            else:
                orientation = image.getexif().get(_ORIENTATION_TAG, 1)
            if _oriented_on_open(image):  # the size Pillow reports already has the orientation applied
                orientation = 1
    except ImageError:
        raise
    except _DECODER_ERRORS as error:
        raise ImageError(f"cannot read image {str(path)!r}: {error or type(error).__name__}") from error
    return (width, height) if orientation in _TRANSPOSED_ORIENTATIONS else (height, width)


def _oriented_on_open(image: Image.Image) -> bool:
    """Whether Pillow reports ``image.size`` with its EXIF orientation already applied: recent Pillow releases open
    TIFF files so (their header's width and height swapped for orientations 5 to 8), and apply it when loading."""
    tags = getattr(image, "tag_v2", None)
    if tags is None:
        return False
    return image.size != (tags.get(256), tags.get(257))  # ImageWidth, ImageLength as stored


def _png_late_orientation(path: Path) -> int:
    """The EXIF orientation of a PNG file from an ``eXIf`` chunk anywhere in it (1 when it has none), found by
    walking the chunk headers without inflating the pixel data."""
    with path.open("rb") as handle:
        handle.seek(8)  # the signature
        while True:
            head = handle.read(8)
            if len(head) < 8:
                return 1
            length, kind = struct.unpack(">I4s", head)
            if kind == b"IEND":
                return 1
            if kind == b"eXIf":
                exif = Image.Exif()
                exif.load(handle.read(length))
                return exif.get(_ORIENTATION_TAG, 1)
            handle.seek(length + 4, os.SEEK_CUR)


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
        if path.is_symlink():
            raise ImageError(
                f"cannot read image {str(path)!r}: it is a symbolic link that leads to no file (dangling, or a loop)"
            )
        raise ImageError(f"cannot read image {str(path)!r}: no such file")
    if path.is_dir():
        if not os.access(path, os.R_OK | os.X_OK):
            raise ImageError(f"cannot read image {str(path)!r}: it is a folder that cannot be listed (no permission)")
        raise ImageError(f"cannot read image {str(path)!r}: it is a folder")
    raise ImageError(f"cannot read image {str(path)!r}: it is not a regular file (a device, FIFO or socket)")


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


#: The largest width or height each format's encoder writes (larger ones fail inside the encoder, and libjpeg
#: prints its own line on stderr before it does).
_MAX_SIDE = {"JPEG": 65_500, "WEBP": 16_383}


def write_image(image: Tensor, path: str | os.PathLike[str]) -> None:
    """Write a ``(3, H, W)`` uint8 or float-in-[0,1] tensor atomically; format from the suffix (JPEG at quality 95).

    The suffix must be one camdegrade reads back (:data:`IMAGE_EXTENSIONS`). Refused before anything is written,
    naming what was expected: a non-tensor, another shape, an integer dtype other than uint8, NaN or infinite values,
    floats on another scale than [0, 1] (further than 0.1 outside it), an image without pixels or larger than the
    format stores (an :class:`~camdegrade.errors.ImageError`, like an encoder's failure).
    """
    path = Path(path)
    _check_writable_image(image, path)
    image_format = Image.registered_extensions().get(path.suffix.lower())
    if image.dtype != torch.uint8:
        image = unit_to_bytes(as_unit(image.detach(), clamp=True))
    pil = Image.fromarray(image.permute(1, 2, 0).cpu().numpy())
    options = {"quality": 95} if image_format == "JPEG" else {}
    with atomic_path(path) as temporary:  # names file-system errors by the target
        try:
            pil.save(temporary, format=image_format, **options)
        except (ValueError, struct.error) as error:  # Pillow's encoders raise these besides OSError
            raise ImageError(f"cannot write image {str(path)!r}: {error}") from error
        except OSError as error:
            if error.filename is not None:
                raise  # the file system's, not the encoder's
            raise ImageError(f"cannot write image {str(path)!r}: {error}") from error


def _check_writable_image(image: Any, path: Path) -> None:
    """Refuse, naming ``path``, what :func:`write_image` cannot write faithfully (see there)."""
    if not isinstance(image, Tensor):
        raise TypeError(f"image must be a torch.Tensor shaped (3, H, W), got {type(image).__name__} for {str(path)!r}")
    if image.ndim != 3 or image.shape[0] != 3:
        raise ValueError(f"image must have shape (3, H, W), got shape {tuple(image.shape)} for {str(path)!r}")
    if image.is_meta or image.layout != torch.strided:
        kind = "meta" if image.is_meta else "sparse"
        raise TypeError(f"image must be a dense tensor holding data, got a {kind} tensor for {str(path)!r}")
    if image.dtype != torch.uint8 and not image.is_floating_point():
        raise TypeError(f"image must be uint8 or floating point in [0, 1], got dtype={image.dtype} for {str(path)!r}")
    if path.suffix.lower() not in IMAGE_EXTENSIONS:
        known = ", ".join(sorted(IMAGE_EXTENSIONS))
        raise ValueError(f"path must end in an image extension camdegrade reads ({known}), got {str(path)!r}")
    height, width = image.shape[1:]
    image_format = Image.registered_extensions()[path.suffix.lower()]
    limit = _MAX_SIDE.get(image_format)
    if height == 0 or width == 0:
        raise ValueError(f"cannot write an image without pixels (shape {tuple(image.shape)}) to {str(path)!r}")
    if limit is not None and max(height, width) > limit:  # an ImageError: a batch lists it and goes on
        raise ImageError(
            f"cannot write image {str(path)!r}: {image_format} stores at most {limit} px a side, got height {height} "
            f"and width {width}; write it as .png or .tif, or resize it"
        )
    if image.dtype == torch.uint8:
        return
    problem = off_unit_scale(image)
    if problem == NOT_FINITE:
        raise ValueError(f"image to write to {str(path)!r} contains NaN or infinite values")
    if problem is not None:
        raise ValueError(f"float images are written from [0, 1], got {problem} for {str(path)!r}; {SCALE_HINT}")
