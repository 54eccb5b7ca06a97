"""The JPEG stage from the camera's own photos: the quality read from the captures' quantisation tables, or, for
lossless files that show 8×8 block edges (JPEGs saved again: the tables are gone), estimated from their spectrum
with a warning."""

from __future__ import annotations

import io
import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import ClassVar

from torch import Tensor

from camdegrade.effects import JPEG, Effect
from camdegrade.effects.base import evenly_spaced
from camdegrade.fitting.steps.base import Verdict
from camdegrade.fitting.unpaired.bench import UnpairedFit, UnpairedStep
from camdegrade.fitting.unpaired.spectrum import mean_spectrum
from camdegrade.measures.blocks import block_phase_energy

__all__ = ["JpegFromBlocks", "JpegTables", "block_edge_ratio", "quality_from_tables"]

#: Gradient energy on the 8×8 block edges, relative to the mean, above which files without a quantisation table
#: look like JPEGs saved again in a lossless format.
BLOCK_EDGE_RATIO = 1.08
#: Qualities tried for captures that show JPEG blocks but carry no quantisation table, on this many crops.
JPEG_QUALITIES = (*range(30, 100, 5), 98)
QUALITY_IMAGES = 12
BLOCKS_WARNING = "the captures show 8×8 block edges"


@dataclass(frozen=True)
class JpegTables(UnpairedStep):
    """The JPEG step: the median quality of the captures' quantisation tables (their spread as its jitter, the share
    of JPEG files as its probability); for captures that are no JPEG files, their 8×8 block edges: above
    :data:`BLOCK_EDGE_RATIO` a quality is estimated later (:class:`JpegFromBlocks`), once the chain before the codec
    stands."""

    name: ClassVar[str] = "jpeg"
    kinds: ClassVar[tuple[type[Effect], ...]] = (JPEG,)

    def propose(self, fit: UnpairedFit) -> list[tuple[int, bool]] | Verdict:
        tables = fit.captures.tables
        if tables:
            return [quality_from_tables(table) for table in tables]
        ratio = block_edge_ratio(evenly_spaced(fit.captures.images, 32))
        if ratio > BLOCK_EDGE_RATIO:
            fit.block_ratio = ratio  # a quality is estimated from the blocks once the chain before it stands
        else:
            fit.not_fit([JPEG], "the captures are not JPEG files and show no 8×8 blocks")
        return Verdict({"jpeg_files": 0, "block_edge_ratio": round(ratio, 3)})

    def judge(self, fit: UnpairedFit, found: list[tuple[int, bool]]) -> dict:
        tables, count = fit.captures.tables, len(fit.captures.images)
        qualities = sorted(quality for quality, _ in found)
        median = qualities[len(qualities) // 2]
        jitter = max(abs(qualities[0] - median), abs(qualities[-1] - median))
        fit.keep(JPEG(median, quality_jitter=jitter, probability=len(tables) / count))
        fit.say(f"jpeg: quality {median} read from {len(tables)} files' quantisation tables")
        return {
            "jpeg_files": len(tables),
            "quality": median,
            "qualities": [qualities[0], qualities[-1]],
            "standard_tables": all(exact for _, exact in found),
        }


@dataclass(frozen=True)
class JpegFromBlocks(UnpairedStep):
    """Captures that were JPEGs once but carry no table: the quality whose simulation has the captures' mean
    spectrum (:data:`JPEG_QUALITIES`; the codec acts on the top bands), with a warning that it is an estimate.

    The block-edge ratio only says *that* there was a codec: as a measure of its quality it is the content's
    (City100's captures range 0.87–2.10 per image, their clean images 0.88–1.52; 20 captures' mean 1.20, 16
    other captures' 1.10), and matching it chose quality 90, whose block edges put +0.77 log2 too much power
    into the held-out top band."""

    name: ClassVar[str] = "jpeg"
    kinds: ClassVar[tuple[type[Effect], ...]] = (JPEG,)

    def applies(self, fit: UnpairedFit) -> bool:
        return fit.block_ratio is not None

    def propose(self, fit: UnpairedFit) -> dict[int, float]:
        crops = evenly_spaced(fit.sets.spectrum_crops, QUALITY_IMAGES)
        chain, real = fit.chain(jpeg=None), fit.sets.real_spectrum

        def mismatch(quality: int) -> float:
            simulated = fit.simulate([*chain, JPEG(quality)], crops, "unpaired-blocks")
            return float((mean_spectrum(simulated) - real).pow(2).mean())

        return {quality: mismatch(quality) for quality in JPEG_QUALITIES}

    def judge(self, fit: UnpairedFit, mismatch: dict[int, float]) -> dict:
        quality = min(mismatch, key=mismatch.__getitem__)
        fit.keep(JPEG(quality))
        fit.warnings = [warning for warning in fit.warnings if not warning.startswith(BLOCKS_WARNING)]
        fit.warnings.append(
            f"{BLOCKS_WARNING} ({fit.block_ratio:.2f}× the mean gradient energy; above "
            f"{BLOCK_EDGE_RATIO} means JPEG blocks) but are not JPEG files, so their quantisation tables are gone "
            f"(JPEGs saved again as PNG?): the jpeg stage's quality {quality} is estimated from the captures' "
            "spectrum; fit from the camera's original JPEG files for the exact one"
        )
        fit.say(f"jpeg: quality {quality} estimated from the spectrum (no quantisation table)")
        return {
            **fit.records[self.name],
            "quality_from_spectrum": quality,
            "spectrum_mismatch": round(mismatch[quality], 4),
        }


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


def block_edge_ratio(images: Sequence[Tensor]) -> float:
    """Mean gradient energy on the 8×8 block edges relative to the mean over the grid's phases (1: no blocks)."""
    ratios = []
    for image in images:
        num, den = block_phase_energy(image)
        ratios.append(float(((num[7] + num[15]) / 2) / den[0].clamp_min(1e-12)))
    return sum(ratios) / len(ratios)
