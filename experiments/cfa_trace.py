"""A Bayer mosaic's trace (:mod:`camdegrade.measures.traces.mosaic`) in the foreign cameras' captures and in the real
pairs of ../shared/data/real-pairs, captures and clean images: per set, the colour route's least trace and its layout,
the clean images' trace there, then the luma route's least trace, its form's bootstrap bound (since the seventh stop:
:mod:`camdegrade.measures.traces.mosaic_form`; the table of docs/results.md's "A colour filter array among the default
stages" was printed with the old bound of the ratio), whether the captures' luma phases come in a mosaic's order and
the clean images' hold its form, and whether :func:`~camdegrade.measures.traces.mosaic.read_mosaic` proposes a stage.
Run from the repo
root (about a minute on one core)::

    OMP_NUM_THREADS=1 PYTHONPATH=src:tests .venv/bin/python experiments/cfa_trace.py
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from camdegrade.functional.sensor.cfa import PATTERNS
from camdegrade.measures.traces.mosaic import mosaic_trace, read_mosaic

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from foreign_cameras import camera, scenes

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real-pairs"
CAMERAS = ("phone", "bayer-jpeg", "webcam", "gamma-blur", "zoom-lanczos", "cheap-nearest", "noisy-upscale")
SUBSETS = ("city100_iPhoneX", "polyu_real_noise", "cc15_nam_real_noise", "sidd_samples")


def _unit(image: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(image.transpose(2, 0, 1))).float() / 255.0


def _row(name: str, cleans: list[torch.Tensor], captures: list[torch.Tensor]) -> str:
    traces = {pattern: mosaic_trace(captures, pattern) for pattern in PATTERNS}
    colour = min(PATTERNS, key=traces.__getitem__)
    reading = read_mosaic(cleans, captures, torch.Generator().manual_seed(0))
    luma = reading if reading.route == "luma" else None
    luma_cells = (
        f"{luma.pattern} {luma.trace:.2f} / {luma.form.bound:+.3f} / {luma.ordered} / {luma.cleans_trace:.2f}, "
        f"{luma.cleans_form}"
        if luma is not None and luma.form is not None
        else "–"
    )
    return (
        f"| {name} | {len(captures)} | {colour} {traces[colour]:.2f} / {mosaic_trace(cleans, colour):.2f} | "
        f"{luma_cells} | {'yes, ' + reading.route if reading.proposed() else 'no'} |"
    )


def _real(subset: str, count: int = 16, side: int = 256) -> tuple[list[torch.Tensor], list[torch.Tensor]]:
    """The first ``count`` pairs of ``subset``, centre crops of ``side``² on the 2×2 grid."""
    with open(DATA / "pairs.csv", newline="") as handle:
        rows = [row for row in csv.DictReader(handle) if row["subset"] == subset][:count]
    cleans, captures = [], []
    for row in rows:
        clean, captured = (np.asarray(Image.open(DATA / row[key]).convert("RGB")) for key in ("clean", "captured"))
        top = (min(clean.shape[0], captured.shape[0]) - side) // 4 * 2
        left = (min(clean.shape[1], captured.shape[1]) - side) // 4 * 2
        cleans.append(_unit(clean[top : top + side, left : left + side]))
        captures.append(_unit(captured[top : top + side, left : left + side]))
    return cleans, captures


def main() -> None:
    torch.set_num_threads(1)
    print(
        "| set | images | colour: layout, captures / cleans | luma: layout, trace / form bound / ordered / cleans, "
        "form | proposed |"
    )
    print("|---|---:|---|---|---|")
    originals = scenes(16, 128, seed=9)
    cleans = [_unit(image) for image in originals]
    for name in CAMERAS:
        chain = camera(name)
        print(_row(name, cleans, [_unit(chain(image, seed=(9, i))) for i, image in enumerate(originals)]))
    for subset in SUBSETS:
        if (DATA / "pairs.csv").is_file():
            print(_row(subset, *_real(subset)))


if __name__ == "__main__":
    main()
