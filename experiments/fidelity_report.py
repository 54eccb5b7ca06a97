"""How the City100 experiments show a simulation beside the real captures: the cells of their fidelity tables and
their evidence pictures (a grid of equal tiles, the columns named at the top and each row labelled at the left).

Imported by its siblings (``fidelity_city100.py``, ``fit_city100_unpaired.py``, ``two_sample_city100.py``,
``sharpen_city100.py``), which Python runs with this folder first on the path.
"""

from __future__ import annotations

import argparse
import itertools
from collections.abc import Sequence
from pathlib import Path

import torch.nn.functional as F
from PIL import Image, ImageDraw
from torch import Tensor

from camdegrade.measures.fidelity import BAND_EDGES


def real_pairs_parser(doc: str, data: Path) -> argparse.ArgumentParser:
    """An experiment's parser: its description the first paragraph of ``doc``, ``--data`` the real-pairs folder."""
    parser = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=data)
    return parser


def number(value: float | None, digits: int = 2, sign: bool = False) -> str:
    """``value`` to ``digits`` decimals (with its sign where ``sign``), ``n/a`` for None."""
    if value is None:
        return "n/a"
    return f"{value:+.{digits}f}" if sign else f"{value:.{digits}f}"


def band_heading() -> str:
    """The heading of the band column: ``log2 power sim/real (0–0.05 / ... / 0.35–0.5)``."""
    bands = " / ".join(f"{low:g}–{high:g}" for low, high in itertools.pairwise(BAND_EDGES))
    return f"log2 power sim/real ({bands})"


def band_cell(values: Sequence[float | None]) -> str:
    """The bands' log2 power ratios, signed, ``/`` between them."""
    return " / ".join(number(value, sign=True) for value in values)


def best_window(score: Tensor, side: int) -> tuple[int, int]:
    """Top-left corner of the ``side``² window with the highest mean ``score`` (on an 8-pixel grid)."""
    pooled = F.avg_pool2d(score[None, None].float(), side, stride=8)[0, 0]
    top, left = divmod(int(pooled.argmax()), pooled.shape[1])
    return top * 8, left * 8


def labelled_grid(
    columns: Sequence[str],
    rows: Sequence[tuple[str, Sequence[Image.Image]]],
    tile: int,
    *,
    label_width: int = 100,
    header: int = 16,
    label_drop: int = 0,
) -> Image.Image:
    """``rows`` of ``tile``² pictures 4 pixels apart on white, right of a ``label_width`` margin and below a
    ``header`` that names ``columns``; each row's label at its middle, raised by ``label_drop`` pixels."""
    canvas = Image.new("RGB", (label_width + len(columns) * (tile + 4), header + len(rows) * (tile + 4)), "white")
    draw = ImageDraw.Draw(canvas)
    for column, name in enumerate(columns):
        draw.text((label_width + column * (tile + 4), 2), name, fill="black")
    for row, (label, pictures) in enumerate(rows):
        top = header + row * (tile + 4)
        draw.text((4, top + tile // 2 - label_drop), label, fill="black")
        for column, picture in enumerate(pictures):
            canvas.paste(picture, (label_width + column * (tile + 4), top))
    return canvas


def save_png(image: Image.Image, path: Path) -> None:
    """``image`` at ``path``, its folder made."""
    path.parent.mkdir(parents=True, exist_ok=True)
    image.save(path)
