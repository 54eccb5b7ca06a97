"""Which real images of ../shared/data/real-pairs still hold a JPEG quantisation lattice: for each subset and side
(clean, captured), how many files read as compressed (:func:`camdegrade.measures.traces.quantisation.read_lattice`), how
many are undetermined, the qualities the files' own JPEG tables give where they have them, and the City100 captures
shrunk to 256 px and crops of them upscaled 2× (PIL bicubic), which were once mistaken for JPEGs by their block-edge
energy. The rows of docs/results.md's "JPEG from its quantisation lattice" table. Run from the repo root (about a
minute on 2 cores)::

    OMP_NUM_THREADS=2 .venv/bin/python experiments/jpeg_lattice_real.py
"""

from __future__ import annotations

import csv
from collections import defaultdict
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from camdegrade.fitting.unpaired.steps.jpeg import quality_from_tables
from camdegrade.measures.traces.quantisation import read_lattice

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real-pairs"


def _files() -> dict[tuple[str, str], list[Path]]:
    """The files of each (subset, side), in the manifest's order."""
    found: dict[tuple[str, str], list[Path]] = defaultdict(list)
    with open(DATA / "pairs.csv", newline="") as handle:
        for row in csv.DictReader(handle):
            for side in ("clean", "captured"):
                found[row["subset"], side].append(DATA / row[side])
    return found


def _reading(paths: list[Path], change=None) -> str:
    """``compressed of N (undetermined U); qualities from the tables`` for the files (``change``: a PIL resize)."""
    compressed = undetermined = 0
    qualities = set()
    for path in paths:
        with Image.open(path) as picture:
            tables = getattr(picture, "quantization", None)
            if tables:
                qualities.add(quality_from_tables(tables)[0])
            picture = picture.convert("RGB")
            image = picture if change is None else change(picture)
        reading = read_lattice(torch.from_numpy(np.asarray(image).copy()).permute(2, 0, 1).float() / 255.0)
        compressed += reading.compressed
        undetermined += not reading.determined
    shown = f"qualities from the tables {sorted(qualities)}" if qualities else "no JPEG tables"
    return f"{compressed} of {len(paths)} on the lattice ({undetermined} undetermined); {shown}"


def _shrunk(picture: Image.Image) -> Image.Image:
    return picture.resize((256, round(256 * picture.height / picture.width)), Image.BICUBIC)


def _crop_upscaled(picture: Image.Image) -> Image.Image:
    return picture.crop((0, 0, 192, 192)).resize((384, 384), Image.BICUBIC)


def main() -> None:
    if not DATA.is_dir():
        raise SystemExit(f"needs the real pairs at {DATA}")
    files = _files()
    for (subset, side), paths in sorted(files.items()):
        print(f"{subset:22s} {side:8s} {_reading(paths)}")
    scenes = {f"{number:03d}L" for number in range(36, 56)}  # the unpaired City100 fit's captures
    captures = [path for path in files["city100_iPhoneX", "captured"] if path.stem in scenes]
    print(f"{'city100 036-055 to 256 px':31s} {_reading(captures, _shrunk)}")
    print(f"{'city100 036-055 crops 2x':31s} {_reading(captures, _crop_upscaled)}")


if __name__ == "__main__":
    main()
