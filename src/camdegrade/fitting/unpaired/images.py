"""The two image sets of an unpaired fit: a folder's usable images (:func:`~camdegrade.pairs.folder.read_folder`:
one unreadable or too small file is reported, never stops the batch) with the quantisation tables of those that are
JPEG files, or a list of images (tensors,
numpy arrays, PIL images, as :class:`~camdegrade.CameraDegrade` takes them); and the checks that a side has enough
of them, that they have contrast, and that the two sides are not the same images."""

from __future__ import annotations

import hashlib
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from camdegrade._support.checks import check_int
from camdegrade._support.pixels import NOT_FINITE, SCALE_HINT, as_unit, off_unit_scale
from camdegrade.errors import PairsError
from camdegrade.io import to_rgb
from camdegrade.pairs.folder import read_folder
from camdegrade.pairs.pair import TOO_SMALL

__all__ = [
    "ACCEPTED",
    "MIN_CONTRAST_LEVELS",
    "MIN_IMAGES",
    "MIN_SIDE",
    "SAME_SHARE",
    "ImageSet",
    "Source",
    "check_all_read",
    "check_contrast",
    "check_count",
    "load_images",
    "load_sides",
    "same_images",
]

#: Fewest usable images on each side: set means of fewer images are mostly content.
MIN_IMAGES = 8
#: Smallest side (px) of a usable image: the sensor's resampling trace needs 16×16 (:mod:`camdegrade.measures.
#: resampling`), and smaller images hold no flat region to read noise in.
MIN_SIDE = 16
#: A side whose every image spans fewer levels than this between its 1st and 99th percentiles of luma has no
#: contrast: its quantiles and spectra cannot be matched to anything (10 flat captures gave a tone curve with
#: white=1.4e10).
MIN_CONTRAST_LEVELS = 4.0
#: The clean images are refused as the captures themselves when at least this share of one side's images is also
#: on the other (the same files, or copies): an unpaired fit needs clean images of *other* scenes.
SAME_SHARE = 0.5

Source = str | os.PathLike[str] | Sequence[Any]
ACCEPTED = "a folder of images or a list of images ((3, H, W) tensors, (H, W, 3) numpy arrays or PIL images)"


@dataclass
class ImageSet:
    """The usable images of one side (``(3, H, W)`` floats in [0, 1]), the quantisation tables of those that
    are JPEG files, the files skipped (``{"path", "reason"}``), and each image's digest (of its 8-bit pixels)."""

    images: list[Tensor]
    tables: list[dict[int, list[int]]] = field(default_factory=list)
    skipped: list[dict[str, str]] = field(default_factory=list)
    digests: list[str] = field(default_factory=list)

    def add(self, image: Tensor) -> None:
        # One memory layout: the fit's sums run in layout order, so a channels-last list gave other bytes than the
        # same pixels read from files (and than a checkpoint's fingerprint, which hashes the pixels, can tell).
        image = image.contiguous()
        self.images.append(image)
        self.digests.append(_digest(image))


def load_images(source: Source, argument: str, max_images: int | None = None) -> ImageSet:
    """A folder's images (one unreadable or too small file is skipped and reported, never stops the batch) or a
    sequence of images (each a ``(3, H, W)`` tensor, uint8 or float in [0, 1]; an ``(H, W, 3)`` numpy array of
    the same dtypes; a PIL image, converted to RGB as a file is), of any sizes from :data:`MIN_SIDE` px a side."""
    if isinstance(source, (str, os.PathLike)):
        return _load_folder(Path(source), argument, max_images)
    if not isinstance(source, Sequence) or isinstance(source, (bytes, Tensor, np.ndarray)):
        raise TypeError(f"{argument} must be {ACCEPTED}, got {type(source).__name__}")
    out = ImageSet([])
    for index, item in enumerate(source[:max_images]):
        name = f"{argument}[{index}]"
        image = _as_unit_image(item, name)
        _check_side(image, name)
        out.add(image)
    return out


def _as_unit_image(item: Any, name: str) -> Tensor:
    """One list item as a ``(3, H, W)`` float32 image in [0, 1], or a typed error naming it."""
    from PIL import Image

    if isinstance(item, Image.Image):
        item = torch.from_numpy(np.array(to_rgb(item, source=name))).permute(2, 0, 1)
    elif isinstance(item, np.ndarray):
        if item.ndim != 3 or item.shape[-1] != 3:
            raise ValueError(f"{name} must be an (H, W, 3) numpy image, got shape {item.shape}")
        if item.dtype != np.uint8 and item.dtype.kind != "f":
            raise TypeError(f"{name} must be a uint8 or floating-point numpy image, got dtype={item.dtype}")
        item = torch.from_numpy(np.ascontiguousarray(item)).permute(2, 0, 1)
    elif not isinstance(item, Tensor):
        raise TypeError(f"{name} must be a (3, H, W) tensor, an (H, W, 3) numpy array or a PIL image, got {item!r}")
    if item.ndim != 3 or item.shape[0] != 3:
        raise ValueError(f"{name} must be a (3, H, W) image, got shape {tuple(item.shape)}")
    if item.dtype != torch.uint8 and not item.dtype.is_floating_point:
        raise TypeError(f"{name} must be uint8 (0..255) or floating point in [0, 1], got dtype={item.dtype}")
    item = item.detach().cpu()
    if item.dtype != torch.uint8:
        problem = off_unit_scale(item)
        if problem == NOT_FINITE:
            raise ValueError(f"{name} must be a finite image, got {NOT_FINITE}")
        if problem is not None:
            raise ValueError(f"{name} must be a float image in [0, 1] (or uint8), got {problem}; {SCALE_HINT}")
    return as_unit(item, clamp=True)


def _check_side(image: Tensor, name: str) -> None:
    height, width = image.shape[-2:]
    if min(height, width) < MIN_SIDE:
        raise ValueError(f"{name} must be at least {MIN_SIDE}x{MIN_SIDE} pixels, got {height}x{width}")


def _load_folder(folder: Path, argument: str, max_images: int | None) -> ImageSet:
    if not folder.is_dir():
        raise PairsError(f"{argument} must be a folder holding images, got {str(folder)!r}")
    found = read_folder(folder, max_images, accept=_big_enough)
    out = ImageSet([], skipped=found.skipped_records())
    for image, path in zip(found.images, found.paths, strict=True):
        out.add(as_unit(image).float())
        tables = _quantisation(path)
        if tables is not None:
            out.tables.append(tables)
    return out


def _big_enough(image: Tensor) -> str | None:
    """Why an image is too small for an unpaired fit (:data:`MIN_SIDE`), or ``None``."""
    height, width = image.shape[-2:]
    if min(height, width) < MIN_SIDE:
        return f"{TOO_SMALL}: {height}x{width} pixels, an unpaired fit needs at least {MIN_SIDE}x{MIN_SIDE}"
    return None


def _quantisation(path: Path) -> dict[int, list[int]] | None:
    from PIL import Image

    try:
        with Image.open(path) as image:
            return dict(image.quantization) if image.format == "JPEG" else None
    except (OSError, AttributeError):  # read_image read it; a table it cannot give is no table
        return None


def _digest(image: Tensor) -> str:
    """A digest of the image's 8-bit pixels and shape (the same file read twice, or a copy, gives the same)."""
    pixels = image.mul(255).round().to(torch.uint8).contiguous().numpy()
    return hashlib.sha256(repr(pixels.shape).encode() + pixels.tobytes()).hexdigest()


def check_count(images: ImageSet, argument: str) -> None:
    if len(images.images) < MIN_IMAGES:
        first = f"; first: {images.skipped[0]['path']}: {images.skipped[0]['reason']}" if images.skipped else ""
        raise PairsError(
            f"{argument} must hold at least {MIN_IMAGES} usable images for an unpaired fit (set statistics of "
            f"fewer are mostly content), got {len(images.images)}"
            + (f" ({len(images.skipped)} skipped{first})" if images.skipped else "")
        )


def check_contrast(images: ImageSet, argument: str) -> None:
    """A :class:`PairsError` when every image of the side is flat (:data:`MIN_CONTRAST_LEVELS`)."""
    spans = []
    for image in images.images:
        luma = image.mean(0).flatten()[:: max(1, image[0].numel() // 20_000)] * 255
        spans.append(float(torch.quantile(luma, 0.99) - torch.quantile(luma, 0.01)))
    if max(spans) < MIN_CONTRAST_LEVELS:
        raise PairsError(
            f"{argument}: the images have no contrast (each spans under {MIN_CONTRAST_LEVELS:g} levels between its "
            f"1st and 99th percentiles, at most {max(spans):.2f}): an unpaired fit matches the tones and spectra "
            "of photos of scenes"
        )


def same_images(captures: ImageSet, cleans: ImageSet) -> int:
    """How many of the captures are also clean images (pixel for pixel); a :class:`PairsError` when that is at
    least :data:`SAME_SHARE` of either side (the same folder or files given twice)."""
    shared = len(set(captures.digests) & set(cleans.digests))
    if shared >= SAME_SHARE * min(len(captures.digests), len(cleans.digests)):
        raise PairsError(
            f"the clean images and the captures are the same images ({shared} of {len(captures.digests)} captures "
            f"are also among the {len(cleans.digests)} clean images: the same folder or files given twice?); an "
            "unpaired fit needs the camera's photos and clean images of other scenes"
        )
    return shared


def check_all_read(images: ImageSet, argument: str) -> None:
    """``strict``: every file of the side used; else a :class:`PairsError` whose first line says how many were not
    (the CLI's one line) and whose next lines name each file and why."""
    if images.skipped:
        listed = "\n".join(f"  {entry['path']}: {entry['reason']}" for entry in images.skipped)
        raise PairsError(
            f"{argument}: {len(images.skipped)} file(s) could not be used (strict: fix or remove them, or run "
            f"without strict to skip them)\n{listed}"
        )


def load_sides(
    captured: Source, clean: Source | None, max_images: int | None, strict: bool
) -> tuple[ImageSet, ImageSet | None, list[str]]:
    """Both sides loaded and checked before any fitting (:func:`check_count`, :func:`check_contrast`, with
    ``strict`` :func:`check_all_read`, then :func:`same_images`), and the warnings to record (a few shared
    images)."""
    if max_images is not None:
        check_int("max_images", max_images, minimum=1)
    captures = load_images(captured, "captured", max_images)
    cleans = load_images(clean, "clean", max_images) if clean is not None else None
    for images, side in ((captures, "captured"), (cleans, "clean")):
        if images is not None:
            check_count(images, side)
            if strict:
                check_all_read(images, side)
            check_contrast(images, side)
    shared = same_images(captures, cleans) if cleans is not None else 0
    if not shared:
        return captures, cleans, []
    return (
        captures,
        cleans,
        [f"{shared} captures are also clean images (the same pixels): the clean set is of other scenes"],
    )
