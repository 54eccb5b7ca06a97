"""Bad files made on purpose for the bad-input tests (issue 17): bombs, truncated images, animations, profiles
with hostile metadata or values, and a helper that runs the CLI and returns its exit status and output."""

from __future__ import annotations

import struct
import zlib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from PIL import Image
from safetensors.torch import save_file

from camdegrade.__main__ import main
from camdegrade.io import write_image
from camdegrade.profile import CameraProfile, serialize_metadata

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def png_with_rows(path: Path, height: int, width: int, rows: int) -> Path:
    """An 8-bit RGB PNG whose header claims ``height × width`` but whose (complete, valid) zlib stream holds only
    ``rows`` rows: a decompression bomb when the header is large, a silently short image when it is not."""
    row = b"\x00" + b"\x80" * (3 * width)  # mid-grey rows compress about 1000:1
    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    data = PNG_SIGNATURE + _chunk(b"IHDR", header) + _chunk(b"IDAT", zlib.compress(row * rows, 9))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data + _chunk(b"IEND", b""))
    return path


def good_image(path: Path, size: tuple[int, int] = (24, 32), seed: int = 0) -> Path:
    """A random RGB image of ``size`` = (height, width) written with camdegrade's writer (format from the suffix)."""
    generator = torch.Generator().manual_seed(seed)
    write_image(torch.randint(0, 256, (3, *size), dtype=torch.uint8, generator=generator), path)
    return path


def cut_image(path: Path, keep: float = 0.5, size: tuple[int, int] = (24, 32), seed: int = 0) -> Path:
    """A valid image whose file is cut after ``keep`` of its bytes (the header stays readable)."""
    good_image(path, size, seed)
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])
    return path


def animated(path: Path, frames: int = 3, image_format: str | None = None) -> Path:
    """An animated image (GIF, WebP or APNG, from the suffix) of ``frames`` different 16×16 frames."""
    rng = np.random.default_rng(1)
    pictures = [Image.fromarray(rng.integers(0, 256, (16, 16, 3), dtype=np.uint8)) for _ in range(frames)]
    path.parent.mkdir(parents=True, exist_ok=True)
    pictures[0].save(path, format=image_format, save_all=True, append_images=pictures[1:], duration=100, loop=0)
    return path


def profile_file(
    path: Path,
    profile: CameraProfile,
    metadata: Mapping[str, Any] | None = None,
    tensors: Mapping[str, torch.Tensor] | None = None,
) -> Path:
    """``profile`` saved as is, but with metadata keys and tensors replaced by ``metadata`` and ``tensors``."""
    state = {key: value.contiguous() for key, value in profile.state_dict().items()}
    state.update(tensors or {})
    save_file(state, str(path), metadata=serialize_metadata({**profile.metadata(), **(metadata or {})}))
    return path


def run_cli(argv: Sequence[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    """``camdegrade ARGV`` in this process: ``(exit status, stdout, stderr)``; usage errors give status 2."""
    try:
        status = main([str(arg) for arg in argv], prog="camdegrade")
    except SystemExit as stop:
        status = stop.code if isinstance(stop.code, int) else 1
    except KeyboardInterrupt:  # escaped the CLI: reported as a status no command returns
        status = -2
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def one_line_error(err: str) -> str:
    """The single stderr line of a failed command (asserting there is exactly one, and no traceback)."""
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]
