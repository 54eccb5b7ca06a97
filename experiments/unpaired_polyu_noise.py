"""The unpaired fit on REAL PolyU captures (issue 43/44's speckle case): flat-input noise against the captures' own.

The recipe: the PolyU pairs sorted by file name; the captures are centre crops of 128² of the first 10 noisy shots
(``_real``, Canon 5D Mk II at ISO 3200 and 6400), saved as JPEG quality 85; the clean set is the centre crops of
128² of the mean frames (``_mean``) of every *other* scene (89, five cameras). ``fit_unpaired`` sees those two
folders only. Printed: the stages kept, the fit's own check (``quality["unpaired_fidelity"]``) and warnings, the
noise stage's level table, and for flat grey inputs the std the profile adds per channel beside the captures' real
noise at that output level (clean-referenced: each capture against its own scene's mean frame, on its flat pixels;
the fit never sees those means). With ``--png``, clean | real | simulated for two scenes at 2× (nearest) and
flat greys at 1:1. Run from the repo root::

    OMP_NUM_THREADS=1 .venv/bin/python experiments/unpaired_polyu_noise.py [REAL_PAIRS_DIR] [--png OUT.png]
"""

from __future__ import annotations

import argparse
import csv
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from camdegrade import CameraProfile
from camdegrade._support.pixels import as_unit
from camdegrade.fitting.unpaired import fit_unpaired
from camdegrade.functional.analysis.images import flat_mask
from camdegrade.functional.analysis.noise import NoiseSums
from camdegrade.io import read_image

SIDE, CAPTURES = 128, 10
FLAT_LEVELS = tuple(round(0.05 + 0.1 * step, 2) for step in range(10))


def default_real_pairs_dir() -> Path:
    return Path(__file__).resolve().parents[2] / "shared" / "data" / "real-pairs"


def _scene(path: str) -> str:
    return Path(path).name.rsplit("_", 2)[0].rstrip("_")


def _crop(path: Path) -> np.ndarray:
    array = np.asarray(Image.open(path).convert("RGB"))
    top, left = (array.shape[0] - SIDE) // 2, (array.shape[1] - SIDE) // 2
    return array[top : top + SIDE, left : left + SIDE]


def write_sets(root: Path, folder: Path) -> tuple[Path, Path, list[Path]]:
    """The captures (JPEG q85), the clean set (PNG) and the captures' own mean frames (PNG, for the truth only)."""
    with open(root / "pairs.csv", newline="") as handle:
        rows = sorted(
            (r for r in csv.DictReader(handle) if r["subset"] == "polyu_real_noise"), key=lambda r: r["clean"]
        )
    captured_rows = rows[:CAPTURES]
    scenes = {_scene(row["clean"]) for row in captured_rows}
    clean_rows = [row for row in rows[CAPTURES:] if _scene(row["clean"]) not in scenes]
    captured, clean, means = folder / "captured", folder / "clean", folder / "captured_mean"
    for path in (captured, clean, means):
        path.mkdir(parents=True)
    for index, row in enumerate(captured_rows):
        Image.fromarray(_crop(root / row["captured"])).save(captured / f"{index:02d}.jpg", quality=85)
        Image.fromarray(_crop(root / row["clean"])).save(means / f"{index:02d}.png")
    for index, row in enumerate(clean_rows):
        Image.fromarray(_crop(root / row["clean"])).save(clean / f"{index:02d}.png")
    return captured, clean, sorted(means.iterdir())


def real_noise(captured: Path, means: list[Path]) -> torch.Tensor:
    """``(3, BINS)`` std (8-bit levels) of each capture against its own mean frame, on the mean's flat pixels."""
    total = NoiseSums.zeros()
    for mean_path in means:
        real = as_unit(read_image(captured / f"{mean_path.stem}.jpg")).float()
        clean = as_unit(read_image(mean_path)).float()
        total = total + NoiseSums.measure(real - clean, clean, flat_mask(clean), clipping=real)
    return total.std(500)


def flat_noise(profile: CameraProfile, seed: int = 0) -> list[tuple[float, torch.Tensor, torch.Tensor]]:
    """``(input level, output mean (3,), output std (3,))`` in 8-bit levels for flat greys through ``profile``."""
    rows = []
    generator = torch.Generator().manual_seed(seed)
    for level in FLAT_LEVELS:
        grey = torch.full((1, 3, SIDE, SIDE), level)
        with torch.no_grad():
            out = profile(grey, profile.make_params(grey.shape, generator))[0] * 255
        rows.append((level, out.mean((1, 2)), out.std((1, 2))))
    return rows


def measure(root: Path, png: Path | None = None) -> dict:
    """Fit the recipe and return its numbers (see the module)."""
    with tempfile.TemporaryDirectory() as scratch:
        captured, clean, means = write_sets(root, Path(scratch))
        profile = fit_unpaired(captured, clean, seed=0)
        truth = real_noise(captured, means)
        flats = flat_noise(profile)
        if png is not None:
            _write_png(profile, captured, means, png)
    noise = [effect for effect in profile.effects if effect.name == "noise"]
    worst = max(float(std.max()) for _, _, std in flats) / float(truth.nan_to_num(0.0).max())
    return {
        "kept": profile.effect_names,
        "fidelity": profile.quality["unpaired_fidelity"],
        "warnings": profile.fitted.get("warnings", []),
        "notes": profile.fitted.get("notes", []),
        "levels": (noise[0].levels * 255).double() if noise else None,
        "truth": truth,
        "flats": flats,
        "flat_over_real": worst,
    }


def _tile(image: torch.Tensor, zoom: int = 1) -> np.ndarray:
    array = (image.clamp(0, 1).permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
    return np.kron(array, np.ones((zoom, zoom, 1), np.uint8))


def _write_png(profile: CameraProfile, captured: Path, means: list[Path], png: Path) -> None:
    """Row 1: clean | real | simulated of two scenes, 48² crops at 2× (nearest); row 2: flat 0.35, 0.55, 0.75 at
    1:1 through the profile."""
    generator = torch.Generator().manual_seed(1)
    texture = []
    for mean_path in (means[3], means[6]):
        clean = as_unit(read_image(mean_path)).float()
        real = as_unit(read_image(captured / f"{mean_path.stem}.jpg")).float()
        with torch.no_grad():
            simulated = profile(clean[None], profile.make_params((1, *clean.shape), generator))[0]
        texture += [_tile(image[:, 40:88, 40:88], 2) for image in (clean, real, simulated)]
    flats = []
    for level in (0.35, 0.55, 0.75):
        grey = torch.full((1, 3, 96, 96), level)
        with torch.no_grad():
            flats.append(_tile(profile(grey, profile.make_params(grey.shape, generator))[0]))
    gap = np.full((96, 4, 3), 255, np.uint8)
    top = np.concatenate([part for tile in texture for part in (tile, gap)], 1)
    bottom = np.concatenate([part for tile in flats for part in (tile, gap)], 1)
    bottom = np.pad(bottom, ((4, 0), (0, top.shape[1] - bottom.shape[1]), (0, 0)), constant_values=255)
    Image.fromarray(np.concatenate([top, bottom], 0)).save(png)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("root", nargs="?", type=Path, default=default_real_pairs_dir())
    parser.add_argument("--png", type=Path, default=None, help="write clean | real | simulated here")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    result = measure(args.root, args.png)
    print("kept:", result["kept"])
    print("own check:", result["fidelity"])
    print("warnings:", result["warnings"])
    print("notes:", result["notes"])
    if result["levels"] is not None:
        print(
            "noise levels (8-bit, per channel and knot):",
            [[round(v, 1) for v in row] for row in result["levels"].tolist()],
        )
    print("real noise by bin (clean-referenced):", [[round(v, 1) for v in row] for row in result["truth"].tolist()])
    print("| flat input | output mean R G B | added std R G B |\n|---|---|---|")
    for level, mean, std in result["flats"]:
        print(f"| {level:.2f} | {' '.join(f'{v:.1f}' for v in mean)} | {' '.join(f'{v:.1f}' for v in std)} |")
    print(f"largest flat std over the captures' largest real noise: {result['flat_over_real']:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
