"""The one reader of a folder of images (the unpaired fit's two sets, a distillation's clean images, the unpaired
diagnosis): every image under it in sorted order, each file that cannot be read reported with the reason and left
out, never the end of the batch."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from torch import Tensor

from camdegrade.errors import ImageError
from camdegrade.io import iter_images, read_image
from camdegrade.pairs.pair import UNREADABLE

__all__ = ["FolderImages", "read_folder"]


@dataclass
class FolderImages:
    """The readable images of a folder (uint8 ``(3, H, W)``, EXIF orientation applied), their paths, and the files
    left out, each with why (:attr:`skipped`: ``(path, error)``)."""

    images: list[Tensor] = field(default_factory=list)
    paths: list[Path] = field(default_factory=list)
    skipped: list[tuple[Path, str]] = field(default_factory=list)

    def skipped_records(self) -> list[dict[str, str]]:
        """The files left out as ``{"path", "reason"}`` (``"unreadable: <error>"``), as a report lists them."""
        return [{"path": str(path), "reason": f"{UNREADABLE}: {error}"} for path, error in self.skipped]


def read_folder(folder: str | os.PathLike[str], max_images: int | None = None) -> FolderImages:
    """The images under ``folder`` (:func:`~camdegrade.io.iter_images`: recursively, sorted), at most
    ``max_images`` readable ones (the first); a file that cannot be read is recorded in ``skipped`` and left out.
    The caller checks that ``folder`` is one (each workflow says so in its own words)."""
    out = FolderImages()
    for path in iter_images(folder):
        if max_images is not None and len(out.images) >= max_images:
            break
        try:
            out.images.append(read_image(path))
        except ImageError as error:  # one bad file never stops the batch: it is reported
            out.skipped.append((path, str(error)))
            continue
        out.paths.append(path)
    return out
