"""The one reader of a folder of images (the unpaired fit's two sets, a distillation's clean images, the unpaired
diagnosis): every image under it in sorted order, each file that cannot be used reported with the reason and left
out, never the end of the batch."""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

from torch import Tensor

from camdegrade.errors import ImageError
from camdegrade.io import iter_images, read_image
from camdegrade.pairs.pair import UNREADABLE

__all__ = ["FolderImages", "LeftOut", "read_folder"]


class LeftOut(NamedTuple):
    """A file of the folder that was not used: the reason's category (``"unreadable"``, ...) and its detail."""

    path: Path
    category: str
    detail: str

    @property
    def reason(self) -> str:
        return f"{self.category}: {self.detail}"


@dataclass
class FolderImages:
    """The usable images of a folder (uint8 ``(3, H, W)``, EXIF orientation applied), their paths, and the files
    left out, each with why."""

    images: list[Tensor] = field(default_factory=list)
    paths: list[Path] = field(default_factory=list)
    skipped: list[LeftOut] = field(default_factory=list)

    def skipped_records(self) -> list[dict[str, str]]:
        """The files left out as ``{"path", "reason"}``, as a report lists them."""
        return [{"path": str(item.path), "reason": item.reason} for item in self.skipped]


def read_folder(
    folder: str | os.PathLike[str],
    max_images: int | None = None,
    accept: Callable[[Tensor], str | None] | None = None,
) -> FolderImages:
    """The images under ``folder`` (:func:`~camdegrade.io.iter_images`: recursively, sorted), at most
    ``max_images`` usable ones (the first). A file that cannot be read, or whose image ``accept`` gives a reason
    to leave out (``"<category>: <detail>"``), is recorded in ``skipped``. The caller checks that ``folder`` is one
    (each workflow says so in its own words)."""
    out = FolderImages()
    for path in iter_images(folder):
        if max_images is not None and len(out.images) >= max_images:
            break
        try:
            image = read_image(path)
        except ImageError as error:  # one bad file never stops the batch: it is reported
            out.skipped.append(LeftOut(path, UNREADABLE, str(error)))
            continue
        refused = accept(image) if accept is not None else None
        if refused is not None:
            category, _, detail = refused.partition(": ")
            out.skipped.append(LeftOut(path, category, detail))
            continue
        out.images.append(image)
        out.paths.append(path)
    return out
