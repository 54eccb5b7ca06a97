"""Bad image files (issue 17): decompression bombs, truncated data, animations and paths through files are refused
with a typed error naming the file, before anything large is allocated."""

from __future__ import annotations

import struct
import warnings
import zlib
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image, ImageFile, PngImagePlugin

import camdegrade.io
from bad_inputs import animated, cut_image, good_image, png_with_rows
from camdegrade.errors import CamdegradeError
from camdegrade.io import read_image, read_image_size, write_image


def test_a_bomb_is_refused_from_its_header(tmp_path: Path) -> None:
    path = png_with_rows(tmp_path / "bomb.png", 12000, 12000, rows=50)
    assert path.stat().st_size < 4096
    with pytest.raises(OSError, match=r"bomb\.png.*12000x12000 px \(144000000 pixels\)") as info:
        read_image(path)
    assert isinstance(info.value, CamdegradeError)


def test_the_pixel_cap_holds_when_pillows_own_limit_is_switched_off(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", None)  # what many training scripts do
    monkeypatch.setattr(camdegrade.io, "MAX_PIXELS", 300 * 300)
    path = png_with_rows(tmp_path / "big.png", 400, 400, rows=4)
    with pytest.raises(OSError, match=r"big\.png.*160000 pixels.*MAX_PIXELS \(90000\)"):
        read_image(path)
    assert read_image(good_image(tmp_path / "small.png", (200, 300))).shape == (3, 200, 300)


def test_a_header_of_ten_billion_pixels_is_a_typed_error(tmp_path: Path) -> None:
    path = png_with_rows(tmp_path / "huge.png", 100_000, 100_000, rows=1)
    for read in (read_image, read_image_size):
        with pytest.raises(OSError, match=r"huge\.png.*10000000000 pixels") as info:
            read(path)
        assert isinstance(info.value, CamdegradeError)


def test_a_png_missing_rows_is_refused(tmp_path: Path) -> None:
    path = png_with_rows(tmp_path / "short.png", 64, 64, rows=8)
    with Image.open(path) as image:  # what Pillow alone does: the missing rows come back black, silently
        image.load()
        assert np.asarray(image)[8:].max() == 0
    with pytest.raises(OSError, match=r"short\.png.*truncated.*8 of 64 rows"):
        read_image(path)


def test_a_complete_png_still_reads(tmp_path: Path) -> None:
    for interlace in (0, 1):
        pixels = np.random.default_rng(interlace).integers(0, 256, (37, 29, 3), dtype=np.uint8)
        path = tmp_path / f"ok{interlace}.png"
        Image.fromarray(pixels).save(path, interlace=interlace)
        assert torch.equal(read_image(path), torch.from_numpy(pixels).permute(2, 0, 1))
    gray = tmp_path / "gray16.png"
    Image.fromarray(np.full((9, 11), 40000, dtype=np.uint16)).save(gray)
    assert read_image(gray).shape == (3, 9, 11)


@pytest.mark.parametrize("suffix", [".png", ".jpg", ".webp", ".bmp", ".tif"])
def test_a_cut_file_is_refused(tmp_path: Path, suffix: str) -> None:
    path = cut_image(tmp_path / f"cut{suffix}", keep=0.6)
    with pytest.raises(OSError, match=rf"cut\{suffix}"):
        read_image(path)


def test_reading_never_switches_on_pillows_truncated_loading() -> None:
    assert ImageFile.LOAD_TRUNCATED_IMAGES is False


@pytest.mark.parametrize(
    "name, image_format", [("anim.gif", None), ("anim.webp", None), ("anim.png", "PNG"), ("pages.tif", None)]
)
def test_an_image_with_several_frames_is_refused(tmp_path: Path, name: str, image_format: str | None) -> None:
    path = animated(tmp_path / name, frames=3, image_format=image_format)
    with pytest.raises(OSError, match=rf"{name.replace('.', '[.]')}' has 3 frames.*only still images") as info:
        read_image(path)
    assert isinstance(info.value, CamdegradeError)


def test_a_phone_jpeg_with_an_embedded_preview_still_reads(tmp_path: Path) -> None:
    """MPO files (phone JPEGs carrying a second, preview picture) are one photo: frame 0 is it."""
    rng = np.random.default_rng(2)
    first, second = (Image.fromarray(rng.integers(0, 256, (16, 24, 3), dtype=np.uint8)) for _ in range(2))
    path = tmp_path / "phone.jpg"
    first.save(path, format="MPO", save_all=True, append_images=[second])
    with Image.open(path) as image:
        assert image.format == "MPO" and image.n_frames == 2
    assert read_image(path).shape == (3, 16, 24)


def test_a_malformed_png_chunk_names_the_file(tmp_path: Path) -> None:
    """Found by fuzzing: Pillow raises ValueError (not OSError) for some corrupt PNG chunks."""
    path = good_image(tmp_path / "text.png")
    data = path.read_bytes()
    # A zTXt chunk that inflates past Pillow's text limit ("Decompressed data too large").
    payload = b"k\x00\x00" + zlib.compress(b"x" * (PngImagePlugin.MAX_TEXT_CHUNK + 10), 9)
    chunk = struct.pack(">I", len(payload)) + b"zTXt" + payload
    chunk += struct.pack(">I", zlib.crc32(b"zTXt" + payload) & 0xFFFFFFFF)
    path.write_bytes(data[:33] + chunk + data[33:])  # after the signature and IHDR
    with pytest.raises(OSError, match=r"text\.png") as info:
        read_image(path)
    assert isinstance(info.value, CamdegradeError)


def test_writing_through_a_regular_file_says_so(tmp_path: Path) -> None:
    blocker = good_image(tmp_path / "file.png")
    with pytest.raises(OSError, match=r"file\.png' is a file, not a folder"):
        write_image(torch.zeros(3, 4, 4, dtype=torch.uint8), blocker / "x.png")
    with pytest.raises(OSError, match=r"file\.png' is a file, not a folder"):
        read_image(blocker / "x.png")


def test_a_bomb_warning_never_reaches_the_caller(tmp_path: Path) -> None:
    """Between Pillow's warning limit and its error limit Pillow only warns; camdegrade refuses instead."""
    path = png_with_rows(tmp_path / "warn.png", 10000, 9000, rows=1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(OSError, match=r"warn\.png.*90000000 pixels"):
            read_image(path)
