"""The mosaic form's bars from the null (issue 42): the luma phases' checker contrast χ against their row and column
contrast (:mod:`camdegrade.measures.traces.mosaic_form`) on sets without a mosaic of their own making (clean images,
JPEG 10-95, PIL and torch upscales by 1.25-3, a sample-aligned 2× bilinear upscale with noise and JPEG, the foreign
cameras without a mosaic, real captures) and on Bayer cameras (the bench's bayer-jpeg and phone, and two that are not
in it: BGGR with OpenCV's edge-aware demosaic and JPEG 88, RGGB bilinear with JPEG 60).

For each set and 10 / 32 / 64 images: χ, the row and column contrast, their ratio, the bootstrap bound of the form's
margin and whether :func:`~camdegrade.measures.traces.mosaic.read_mosaic` proposes a stage. Numbers in
docs/results.md, *The cfa stage proposed by the mosaic's form*. Run from the repo root (about 40 s of CPU)::

    OMP_NUM_THREADS=1 PYTHONPATH=src:tests .venv/bin/python experiments/mosaic_form_null.py [real-pairs folder]
"""

from __future__ import annotations

import csv
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from PIL import Image

from camdegrade.functional.sensor.cfa import luma_phases
from camdegrade.measures.traces.mosaic import read_mosaic
from camdegrade.measures.traces.mosaic_form import phase_contrasts, read_form
from foreign_cameras import camera, scenes
from mosaic_cameras import aligned_upscale, bggr_camera, jpeg

COUNT, SIZE, SEED = 64, 128, 101


def unit(image: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(image.transpose(2, 0, 1))).float() / 255.0


def pil_upscale(image: np.ndarray, factor: float, method: int) -> np.ndarray:
    height, width = image.shape[:2]
    small = Image.fromarray(image).resize((round(width / factor), round(height / factor)), Image.BOX)
    return np.asarray(small.resize((width, height), method))


def torch_upscale(image: np.ndarray, factor: float) -> np.ndarray:
    x = unit(image)[None]
    small = F.interpolate(x, size=(int(SIZE / factor),) * 2, mode="area")
    up = F.interpolate(small, size=(SIZE, SIZE), mode="bilinear", align_corners=True)[0]
    return (up.clamp(0, 1).permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)


def noisy(image: np.ndarray, rng: np.random.Generator, std: float) -> np.ndarray:
    return np.clip(image + rng.normal(0, std, image.shape), 0, 255).astype(np.uint8)


def null_sets(cleans: list[np.ndarray]) -> dict[str, list[np.ndarray]]:
    rng = np.random.default_rng(1)
    each: dict[str, Callable[[np.ndarray], np.ndarray]] = {
        "clean": lambda c: c,
        **{f"JPEG {q} 4:2:0": (lambda c, q=q: jpeg(c, q)) for q in (10, 30, 50, 75, 95)},
        **{
            f"PIL bicubic ×{f:g}, JPEG 75": (lambda c, f=f: jpeg(pil_upscale(c, f, Image.BICUBIC), 75))
            for f in (1.25, 1.5, 2, 3)
        },
        "PIL bilinear ×2": lambda c: pil_upscale(c, 2, Image.BILINEAR),
        **{f"torch bilinear ×{f:g} (corners)": (lambda c, f=f: torch_upscale(c, f)) for f in (1.25, 1.5, 2, 3)},
        "aligned bilinear ×2": aligned_upscale,
        "aligned bilinear ×2, noise 3": lambda c: noisy(aligned_upscale(c), rng, 3.0),
        "aligned bilinear ×2, JPEG 75": lambda c: jpeg(aligned_upscale(c), 75),
    }
    sets = {name: [make(c) for c in cleans] for name, make in each.items()}
    for name in (
        "webcam",
        "zoom-lanczos",
        "cheap-nearest",
        "noisy-upscale",
        "webcam-jpeg25",
        "gamma-blur",
        "shaky-defocus",
    ):
        chain = camera(name)
        sets[name] = [chain(c, seed=(SEED, i)) for i, c in enumerate(cleans)]
    return sets


def mosaic_sets(cleans: list[np.ndarray]) -> dict[str, list[np.ndarray]]:
    sets = {name: [camera(name)(c, seed=(SEED, i)) for i, c in enumerate(cleans)] for name in ("bayer-jpeg", "phone")}
    sets["BGGR OpenCV EA, JPEG 88 (not in the bench)"] = [bggr_camera(c, (7, i)) for i, c in enumerate(cleans)]
    return sets


def real_sets(folder: Path) -> dict[str, tuple[list[np.ndarray], list[np.ndarray]]]:
    """Per subset of the real pairs, 16 pairs, four 256² crops of each: (captures, clean images)."""
    with (folder / "pairs.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    out = {}
    for subset in sorted({row["subset"] for row in rows}):
        sides: tuple[list[np.ndarray], list[np.ndarray]] = ([], [])
        for row in [row for row in rows if row["subset"] == subset][:16]:
            for key, side in (("captured", sides[0]), ("clean", sides[1])):
                image = np.asarray(Image.open(folder / row[key]).convert("RGB"))
                half = (image.shape[0] // 4 * 2, image.shape[1] // 4 * 2)
                side += [image[y : y + 256, x : x + 256] for y in (0, half[0]) for x in (0, half[1])]
        out[f"{subset} (real)"] = sides
    return out


def row(name: str, captures: list[np.ndarray], cleans: list[np.ndarray]) -> str:
    cells = []
    for count in (10, 32, COUNT):
        count = min(count, len(captures))
        shots = [unit(image) for image in captures[:count]]
        per_image = torch.stack([luma_phases(image) for image in shots])
        rho, kappa, chi = phase_contrasts(per_image.mean(0))
        form = read_form(per_image, torch.Generator().manual_seed(0))
        reading = read_mosaic([unit(c) for c in cleans[:count]], shots, torch.Generator().manual_seed(0))
        proposed = f"{reading.route} {reading.pattern}" if reading.proposed() else "no"
        cells.append(f"{chi:+.3f} / {np.hypot(rho, kappa):.3f} / {form.ratio:.2f} / {form.bound:+.3f} / {proposed}")
    return f"| {name} | " + " | ".join(cells) + " |"


def main() -> None:
    torch.set_num_threads(1)
    cleans = scenes(COUNT, SIZE, seed=SEED)
    print("| set | 10 images: χ / row-column / ratio / bound / proposed | 32 images | 64 images |")
    print("|---|---|---|---|")
    for name, captures in {**null_sets(cleans), **mosaic_sets(cleans)}.items():
        print(row(name, captures, cleans), flush=True)
    folder = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parents[2] / "shared/data/real-pairs"
    if (folder / "pairs.csv").exists():
        for name, (captures, real_cleans) in real_sets(folder).items():
            print(row(name, captures, real_cleans), flush=True)


if __name__ == "__main__":
    main()
