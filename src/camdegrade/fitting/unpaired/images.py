"""The two image sets of an unpaired fit: a folder's readable images (:func:`~camdegrade.pairs.folder.read_folder`:
one unreadable file is reported, never stops the batch) with the quantisation tables of those that are JPEG files, or
a list of tensors; and the check that a side has enough of them."""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from torch import Tensor

from camdegrade._pixels import as_unit
from camdegrade.errors import PairsError
from camdegrade.pairs.folder import read_folder

#: Fewest readable images on each side: set means of fewer images are mostly content.
MIN_IMAGES = 8

Source = str | os.PathLike[str] | Sequence[Tensor]


@dataclass
class ImageSet:
    """The readable images of one side (``(3, H, W)`` floats in [0, 1]), the quantisation tables of those that
    are JPEG files, and the files skipped (``{"path", "reason"}``)."""

    images: list[Tensor]
    tables: list[dict[int, list[int]]] = field(default_factory=list)
    skipped: list[dict[str, str]] = field(default_factory=list)


def load_images(source: Source, argument: str, max_images: int | None = None) -> ImageSet:
    """A folder's images (one unreadable file is skipped and reported, never stops the batch) or a sequence of
    ``(3, H, W)`` tensors (uint8 or float in [0, 1]); of any sizes."""
    if isinstance(source, (str, os.PathLike)):
        return _load_folder(Path(source), argument, max_images)
    if isinstance(source, Sequence) and all(isinstance(image, Tensor) for image in source):
        images = []
        for index, image in enumerate(source[:max_images]):
            if image.ndim != 3 or image.shape[0] != 3:
                raise ValueError(f"{argument}[{index}] must be a (3, H, W) image, got shape {tuple(image.shape)}")
            images.append(as_unit(image.detach().cpu()).float())
        return ImageSet(images)
    raise TypeError(
        f"{argument} must be a folder of images or a list of (3, H, W) tensors, got {type(source).__name__}"
    )


def _load_folder(folder: Path, argument: str, max_images: int | None) -> ImageSet:
    if not folder.is_dir():
        raise PairsError(f"{argument} must be a folder holding images, got {str(folder)!r}")
    found = read_folder(folder, max_images)
    tables = [_quantisation(path) for path in found.paths]
    return ImageSet(
        [as_unit(image).float() for image in found.images],
        [table for table in tables if table is not None],
        found.skipped_records(),
    )


def _quantisation(path: Path) -> dict[int, list[int]] | None:
    from PIL import Image

    try:
        with Image.open(path) as image:
            return dict(image.quantization) if image.format == "JPEG" else None
    except (OSError, AttributeError):  # read_image read it; a table it cannot give is no table
        return None


def check_count(images: ImageSet, argument: str) -> None:
    if len(images.images) < MIN_IMAGES:
        raise PairsError(
            f"{argument} must hold at least {MIN_IMAGES} readable images for an unpaired fit (set statistics of "
            f"fewer are mostly content), got {len(images.images)}"
            + (f" ({len(images.skipped)} unreadable)" if images.skipped else "")
        )
