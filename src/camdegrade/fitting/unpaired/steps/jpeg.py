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

**Kept for the noise the chain adds** (:func:`noise_to_code`), where the clean images are compressed as much: their
content met a codec, but the noise stage adds what no clean image holds, and the camera's noise went through its
codec. On the flat pixels of 10 PolyU captures (Canon 5D Mk II; the dataset's JPEG q75, then q85) against their own
scenes' mean frames, 98 % of the luma DCT coefficients at ``u + v ≥ 6`` of the flat 8×8 blocks are zero (under 0.75)
and the luma differences across block edges carry 3.5× the energy of those inside; the noise stage added after the
clean images' codec read 57–69 % and 0.99×, and the fit's own image-only critic told the simulation from the captures
at 0.85 (docs/results.md, "The PolyU unpaired self-check: the codec the camera's noise went through"). Compressing
those q75 frames again at q85 moves their flat pixels by a std of 0.3 levels. So where the noise stage is asked for and
the captures' flat pixels vary :data:`~camdegrade.fitting.unpaired.steps.noise.NOISE_SHARE` times more than the
clean set's (there is noise for the chain to add), the codec stage is kept, after the noise.
"""

from __future__ import annotations

import io
import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, ClassVar

from camdegrade.effects import JPEG, Effect, Noise
from camdegrade.fitting.steps.base import Verdict
from camdegrade.fitting.unpaired.bench import UnpairedFit, UnpairedStep
from camdegrade.fitting.unpaired.images import ImageSet
from camdegrade.fitting.unpaired.steps.noise import FINE_WINDOW, NOISE_SHARE, captures_noise, flat_sums
from camdegrade.measures.traces.quantisation import FREQUENCIES, read_lattice

__all__ = [
    "UNCOMPRESSED",
    "JpegQuality",
    "SideQualities",
    "codec_stage",
    "noise_to_code",
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
    unless the clean images are compressed as much and there is no noise for the chain to add
    (:func:`noise_to_code`)."""

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
                noise = noise_to_code(fit)
                if noise is None:
                    reason = (
                        f"the captures (median quality {found.median()}) are compressed no more than the clean images "
                        f"({clean}), which a codec stage would compress again"
                    )
                    return self._not_fitted(fit, note, reason).record
                note["for_the_noise"] = noise
                fit.say(
                    f"jpeg: the clean images are compressed as much ({clean}), but the captures' flat pixels vary "
                    f"{noise['captures_std_levels']} levels against {noise['clean_std_levels']}: kept for the noise"
                )
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


def noise_to_code(fit: UnpairedFit) -> dict[str, Any] | None:
    """The captures' and the clean set's flat-pixel noise (pooled std, levels, read at
    :data:`~camdegrade.fitting.unpaired.steps.noise.FINE_WINDOW` as the noise step reads them) where the noise stage
    is asked for and the captures' is at least :data:`~camdegrade.fitting.unpaired.steps.noise.NOISE_SHARE` times the
    clean set's; ``None`` otherwise (no clean set, no noise asked for, or none for the chain to add)."""
    if fit.cleans is None or not fit.wants(Noise):
        return None
    captures = captures_noise(fit, direct=False).pooled_std()
    clean = flat_sums(fit.sets.noise_crops, FINE_WINDOW).pooled_std()
    if not captures >= NOISE_SHARE * clean:  # NaN (too few flat pixels) keeps no codec
        return None
    return {"captures_std_levels": round(captures, 3), "clean_std_levels": round(clean, 3)}
