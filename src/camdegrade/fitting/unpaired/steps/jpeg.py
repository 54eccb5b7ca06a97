"""The unpaired fit's codec step: the JPEG quality of each capture and each clean image, and the stage those give.

A JPEG file's quality is read from its quantisation tables (exact for libjpeg's standard tables, the nearest
standard quality for a camera's own). A lossless file (a JPEG saved again as PNG, a decoded tensor) is read from the
quantisation lattice its pixels still hold (:mod:`camdegrade.measures.traces.quantisation`): the steps found, matched to
the nearest standard luma table; a file that holds none was never block-compressed or was resampled since, and gets no
quality. The 8×8 block-edge energy is not used: a resize leaves as much of it (City100's PNGs shrunk to 256 px read
1.18× the mean, above the 1.08 it took for JPEG blocks) and none of the lattice.

The stage is the captures' qualities (a :class:`~camdegrade.effects.JPEG` mixture with each quality's share of the
images when they differ, compressing the share of images that were compressed), kept only when the captures are
compressed more than the clean images: clean images of the same quality compressed again would lose twice.
"""

from __future__ import annotations

import io
import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, ClassVar

from camdegrade.effects import JPEG, Effect
from camdegrade.fitting.steps.base import Verdict
from camdegrade.fitting.unpaired.bench import UnpairedFit, UnpairedStep
from camdegrade.fitting.unpaired.images import ImageSet
from camdegrade.measures.traces.quantisation import FREQUENCIES, read_lattice

__all__ = [
    "UNCOMPRESSED",
    "JpegQuality",
    "SideQualities",
    "codec_stage",
    "quality_from_steps",
    "quality_from_tables",
    "side_qualities",
    "standard_tables",
]

#: An image without a table or a lattice counts as this quality when the two sides are compared (quality 97 and
#: above leave steps of 1 at the frequencies read, which is no lattice: such images are as good as uncompressed).
UNCOMPRESSED = 100
LATTICE_WARNING = "the captures are not JPEG files but hold JPEG's quantisation lattice"


@dataclass(frozen=True)
class SideQualities:
    """Each image's JPEG quality (``None``: not compressed; images whose pixels could not tell are left out and
    counted as ``undetermined``), where they were read (``"tables"``: every image is a JPEG file; ``"lattice"``: the
    pixels) and whether every table was one of libjpeg's exactly."""

    qualities: list[int | None]
    source: str
    standard: bool
    undetermined: int = 0

    @property
    def compressed(self) -> list[int]:
        return [quality for quality in self.qualities if quality is not None]

    def median(self) -> int | None:
        """The median quality, an uncompressed image counting as :data:`UNCOMPRESSED` (``None``: no image told)."""
        values = sorted(UNCOMPRESSED if quality is None else quality for quality in self.qualities)
        return values[len(values) // 2] if values else None


@dataclass(frozen=True)
class JpegQuality(UnpairedStep):
    """The JPEG step, before every stage fitted through the chain (its quality is read, not fitted): ``propose``
    reads each capture's quality (:func:`side_qualities`), ``judge`` keeps the stage they give (:func:`codec_stage`)
    unless the clean images are compressed as much."""

    name: ClassVar[str] = "jpeg"
    kinds: ClassVar[tuple[type[Effect], ...]] = (JPEG,)

    def propose(self, fit: UnpairedFit) -> SideQualities | Verdict:
        found = side_qualities(fit.captures)
        if not found.compressed:
            return self._not_fitted(
                fit, _note(fit.captures, found), "the captures are not JPEG files and hold no JPEG quantisation lattice"
            )
        return found

    def judge(self, fit: UnpairedFit, found: SideQualities) -> dict[str, Any]:
        note = _note(fit.captures, found)
        if fit.cleans is not None:
            clean = side_qualities(fit.cleans).median()
            note["clean_median_quality"] = clean
            if clean is not None and found.median() >= clean:
                reason = (
                    f"the captures (median quality {found.median()}) are compressed no more than the clean images "
                    f"({clean}), which a codec stage would compress again"
                )
                return self._not_fitted(fit, note, reason).record
        counts = Counter(found.compressed)
        stage = codec_stage(counts, len(found.qualities))
        fit.keep(stage)
        shown = ", ".join(f"{quality} ({count} image{'s' * (count > 1)})" for quality, count in sorted(counts.items()))
        where = "files' quantisation tables" if found.source == "tables" else "images' quantisation lattice"
        line = f"jpeg: {'qualities' if len(counts) > 1 else 'quality'} {shown} read from {sum(counts.values())} {where}"
        if len(counts) > 1:
            line += f"; each simulated image draws its quality from them (centre {int(stage.quality)})"
        fit.say(line)
        if found.source == "lattice":
            fit.warnings.append(
                f"{LATTICE_WARNING} ({len(found.compressed)} of {len(found.qualities)} images: JPEGs saved again "
                "losslessly?): the jpeg stage's qualities are the nearest standard tables to the steps read from "
                "their pixels; fit from the camera's original JPEG files for its exact tables"
            )
        return {**note, "kept": True, "quality": int(stage.quality)}

    @staticmethod
    def _not_fitted(fit: UnpairedFit, note: dict[str, Any], reason: str) -> Verdict:
        fit.not_fit([JPEG], reason)
        fit.say(f"jpeg: not fitted: {reason}")
        return Verdict({**note, "kept": False, "reason": reason})


def _note(captures: ImageSet, found: SideQualities) -> dict[str, Any]:
    """The record's account of what was read: where, how many images at each quality, and how many told none."""
    note: dict[str, Any] = {
        "read_from": found.source,
        "jpeg_files": len(captures.tables),
        "images_per_quality": {str(quality): count for quality, count in sorted(Counter(found.compressed).items())},
        "uncompressed_images": len(found.qualities) - len(found.compressed),
        "undetermined_images": found.undetermined,
    }
    if found.source == "tables":
        note["standard_tables"] = found.standard
    return note


def codec_stage(counts: Counter[int], images: int) -> JPEG:
    """A JPEG stage compressing the share of ``images`` that were compressed, at each quality with its share
    (``counts``: images per quality); one quality is a plain stage, several a mixture centred on their median."""
    qualities = sorted(counts.elements())
    median = qualities[len(qualities) // 2]
    probability = len(qualities) / images
    if len(counts) == 1:
        return JPEG(median, probability=probability)
    mixture = {quality: count / len(qualities) for quality, count in sorted(counts.items())}
    return JPEG(median, probability=probability, mixture=mixture)


def side_qualities(images: ImageSet) -> SideQualities:
    """Each image's quality: from the tables when every image is a JPEG file, else from each image's lattice."""
    if images.tables and len(images.tables) == len(images.images):
        found = [quality_from_tables(table) for table in images.tables]
        return SideQualities([quality for quality, _ in found], "tables", all(exact for _, exact in found))
    readings = [read_lattice(image) for image in images.images]
    qualities = [quality_from_steps(reading.steps) if reading.compressed else None for reading in readings]
    told = [quality for quality, reading in zip(qualities, readings, strict=True) if reading.determined]
    return SideQualities(told, "lattice", False, undetermined=len(readings) - len(told))


def quality_from_steps(steps: Sequence[int | None]) -> int:
    """The libjpeg quality whose luma table is nearest (log ratio, summed) to the steps found at
    :data:`~camdegrade.measures.traces.quantisation.FREQUENCIES`. Only steps of 2 or more count: a frequency read as off
    the lattice may be one whose few coefficients sit in smooth blocks, where the decoder's rounding moves them by
    more than a step of 1 or 2 allows. Qualities 49–51 and 74–75 have the same steps there: a tie goes to the
    multiple of 5 (what software offers), then to the highest."""

    def distance(quality: int) -> float:
        table = standard_tables()[quality][0]
        return sum(
            abs(math.log(step) - math.log(max(table[u * 8 + v], 1)))
            for step, (u, v) in zip(steps, FREQUENCIES, strict=True)
            if step is not None and step >= 2
        )

    return min(range(100, 0, -1), key=lambda quality: (distance(quality), quality % 5 != 0))


@lru_cache(maxsize=1)
def standard_tables() -> dict[int, dict[int, tuple[int, ...]]]:
    """Quality → the quantisation tables libjpeg writes at that quality (as PIL reports them)."""
    from PIL import Image

    out = {}
    for quality in range(1, 101):
        buffer = io.BytesIO()
        Image.new("RGB", (8, 8)).save(buffer, "JPEG", quality=quality)
        with Image.open(buffer) as image:
            out[quality] = {key: tuple(table) for key, table in image.quantization.items()}
    return out


def quality_from_tables(tables: dict[int, Sequence[int]]) -> tuple[int, bool]:
    """The libjpeg quality whose tables are nearest (log ratio, summed) to ``tables``, and whether they are equal
    (a camera with tables of its own gets the nearest standard quality)."""

    def distance(quality: int) -> float:
        reference = standard_tables()[quality]
        total = 0.0
        for key, table in tables.items():
            if key in reference and len(table) == len(reference[key]):
                total += sum(abs(math.log(max(a, 1) / max(b, 1))) for a, b in zip(table, reference[key], strict=True))
        return total

    best = min(range(1, 101), key=distance)
    return best, distance(best) == 0.0
