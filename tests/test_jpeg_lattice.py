"""JPEG's fingerprint in decoded pixels (:mod:`camdegrade.measures.traces.quantisation`), read on images made by parts
that are not ours: scikit-image's photos (the PNG ones; its rocket is a JPEG), resized by PIL's filters, compressed by
PIL's libjpeg and saved again losslessly. A resize leaves no quantisation lattice; a JPEG leaves one whose steps are
its tables', on the 8×8 grid of the origin only."""

from __future__ import annotations

import io

import numpy as np
import pytest
import skimage.data
import torch
from PIL import Image

from camdegrade.fitting.unpaired.steps.jpeg import quality_from_steps, standard_tables
from camdegrade.measures.traces.quantisation import FREQUENCIES, MIN_FREQUENCIES, read_lattice

torch.set_num_threads(1)
FILTERS = {"bilinear": Image.BILINEAR, "bicubic": Image.BICUBIC, "lanczos": Image.LANCZOS, "box": Image.BOX}


def _photos() -> list[Image.Image]:
    """Three crops of 160² from scikit-image's PNG photos (never JPEG-compressed)."""
    crops = []
    for index, name in enumerate(("astronaut", "coffee", "chelsea")):
        photo = Image.fromarray(getattr(skimage.data, name)())
        crops.append(photo.crop((40 * index, 30 * index, 40 * index + 160, 30 * index + 160)))
    return crops


def _tensor(picture: Image.Image) -> torch.Tensor:
    return torch.from_numpy(np.asarray(picture.convert("RGB")).copy()).permute(2, 0, 1)


def _jpeg_then_png(picture: Image.Image, quality: int) -> Image.Image:
    """``picture`` through PIL's JPEG at ``quality``, then saved as PNG and read back (the tables are gone)."""
    compressed, lossless = io.BytesIO(), io.BytesIO()
    picture.save(compressed, "JPEG", quality=quality)
    Image.open(compressed).save(lossless, "PNG")
    return Image.open(lossless)


@pytest.mark.parametrize("factor", [0.3, 0.75, 2.0])
@pytest.mark.parametrize("method", sorted(FILTERS))
def test_a_resize_leaves_no_lattice(method: str, factor: float) -> None:
    for photo in _photos():
        side = round(160 * factor)
        reading = read_lattice(_tensor(photo.resize((side, side), FILTERS[method])))
        assert reading.on_lattice == 0 and not reading.compressed, (method, factor, reading.steps)


@pytest.mark.parametrize("quality", [30, 50, 75, 90, 95])
def test_a_jpeg_saved_again_as_png_holds_its_tables_steps(quality: int) -> None:
    table = standard_tables()[quality][0]
    expected = [table[u * 8 + v] for u, v in FREQUENCIES]
    for photo in _photos():
        reading = read_lattice(_tensor(_jpeg_then_png(photo, quality)))
        assert reading.compressed and reading.on_lattice >= MIN_FREQUENCIES, (quality, reading.steps)
        found = [(step, want) for step, want in zip(reading.steps, expected, strict=True) if step and step >= 2]
        # a frequency with few coefficients off zero (20 to 50) can read a divisor of its step; most read it exactly
        assert sum(step == want for step, want in found) >= 0.8 * len(found), (quality, reading.steps, expected)
        assert quality_from_steps(reading.steps) == quality, (quality, reading.steps)


def test_the_lattice_is_the_last_steps_and_locked_to_the_origin() -> None:
    for photo in _photos():
        jpeg = _jpeg_then_png(photo, 50)
        resized = jpeg.resize((120, 120), Image.BICUBIC)  # the codec, then a resize
        assert not read_lattice(_tensor(resized)).compressed
        shifted = _tensor(jpeg)[:, 4:, 4:]  # the blocks now start half a block from the origin
        assert not read_lattice(shifted).compressed
        assert read_lattice(_tensor(jpeg)[:, 8:, 16:]).compressed  # a crop on the grid keeps it
