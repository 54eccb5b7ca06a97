"""Which local mean the unpaired noise calibration should take off, on issue 43's PolyU case (10 captures of 128²,
JPEG q85; clean = other scenes' mean frames; ``experiments/unpaired_polyu_noise.py``'s sets).

1. **What each window reads**: the rms of ``x − mean_w(x)`` (levels, pooled over channels) on the flat pixels
   (:func:`~camdegrade.functional.analysis.images.noisy_flat_mask`) of the real noise field (each capture less its
   own mean frame, on the capture's flat pixels), of the captures, of the captures' own mean frames on the
   captures' flat pixels (the texture the captures' reading holds) and of the other scenes' mean frames on theirs.
2. **The noise step alone** (:func:`~camdegrade.fitting.unpaired.steps.noise.propose_noise`, the stage as the whole
   chain) calibrated at each window against the fit's clean images (16, evenly spaced) and against the captures'
   own mean frames: its std at mid grey, its level table, and per intensity bin against the 19 held-out Canon 5D
   Mk II shots as ``experiments/unpaired_polyu_truth.py`` reads it (median / worst ``|log2|``, bins within the
   oracle's worst); and the two tables against each other (median / worst ``|log2|`` over the knots).

Run from the repo root::

    OMP_NUM_THREADS=1 .venv/bin/python experiments/unpaired_noise_window.py [REAL_PAIRS_DIR] [--windows 17 5 ...]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from noise_table import _residual_sums
from unpaired_polyu_noise import default_real_pairs_dir, write_sets
from unpaired_polyu_truth import held_out_pairs

from camdegrade import CameraProfile
from camdegrade._support.pixels import as_unit
from camdegrade.effects import Noise
from camdegrade.effects.base import evenly_spaced
from camdegrade.fitting.unpaired.fit import NOISE_IMAGES
from camdegrade.fitting.unpaired.steps.noise import flat_sums, propose_noise
from camdegrade.functional.analysis.images import box_mean, noisy_flat_mask
from camdegrade.io import read_image


def _rms(images: list[torch.Tensor], masks: list[torch.Tensor], window: int) -> float:
    total, count = 0.0, 0
    for image, mask in zip(images, masks, strict=True):
        residual = (image - box_mean(image, window)) * 255.0
        total += float(residual[:, mask].pow(2).sum())
        count += 3 * int(mask.sum())
    return (total / count) ** 0.5


def readings(sets: dict[str, list[torch.Tensor]], windows: list[int]) -> list[list[float]]:
    """Item 1 of the module: one row per window."""
    captures, trues, others = sets["captures"], sets["true"], sets["other"]
    fields = [capture - true for capture, true in zip(captures, trues, strict=True)]
    capture_masks = [noisy_flat_mask(image) for image in captures]
    other_masks = [noisy_flat_mask(image) for image in others]
    columns = [(fields, capture_masks), (captures, capture_masks), (trues, capture_masks), (others, other_masks)]
    return [[round(_rms(images, masks, window), 2) for images, masks in columns] for window in windows]


def _spread(ratio: torch.Tensor) -> tuple[float, float]:
    values = ratio[torch.isfinite(ratio) & (ratio > 0)].log2().abs()
    return round(float(values.median()), 2), round(float(values.max()), 2)


def noise_alone(sets: dict[str, list[torch.Tensor]], held: tuple[list, list], window: int) -> dict:
    """Item 2 of the module at one window."""
    hcleans, hreals = held
    truth = _residual_sums(hreals, hcleans).std()
    oracle = _residual_sums(sets["captures"], sets["true"]).std() / truth
    real = flat_sums(sets["captures"], window)
    out, tables = {}, {}
    for name in ("other", "true"):

        def simulate(noise: Noise | None, cleans: list[torch.Tensor] = sets[name]) -> list[torch.Tensor]:
            return CameraProfile(None, [noise] if noise else []).simulate(cleans, 0, stream="n", eight_bit=True)

        noise = propose_noise(real, simulate, window=window).noise
        sims = CameraProfile(None, [noise]).simulate(hcleans, 1, stream="truth", eight_bit=True)
        fitted = _residual_sums(sims, hcleans).std() / truth
        both = torch.isfinite(fitted) & torch.isfinite(oracle)
        worst = float(oracle[both].log2().abs().max())
        tables[name] = noise.levels.double() * 255
        out[name] = {
            "mid_grey": round(noise.magnitude(), 2),
            "levels": [[round(float(v), 1) for v in row] for row in tables[name]],
            "per_bin": _spread(fitted),
            "within_oracle_worst": f"{int((fitted[both].log2().abs() <= worst).sum())} of {int(both.sum())}",
        }
    out["other_over_true"] = _spread(tables["other"] / tables["true"])
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("root", nargs="?", type=Path, default=default_real_pairs_dir())
    parser.add_argument("--windows", type=int, nargs="+", default=[3, 5, 7, 9, 17])
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as scratch:
        captured, clean, means = write_sets(args.root, Path(scratch))
        load = lambda paths: [as_unit(read_image(path)).float() for path in paths]  # noqa: E731
        sets = {"captures": load(sorted(captured.iterdir())), "true": load(means)}
        sets["other"] = evenly_spaced(load(sorted(clean.iterdir())), NOISE_IMAGES)
        held = held_out_pairs(args.root, Path(scratch) / "held_out")
    print("| window | real noise field | captures | captures' own mean frames | other scenes' mean frames |")
    print("|---|---|---|---|---|")
    for window, row in zip(args.windows, readings(sets, args.windows), strict=True):
        print(f"| {window}×{window} | " + " | ".join(f"{value:.2f}" for value in row) + " |")
    for window in args.windows:
        print(f"noise step alone at {window}×{window}: {noise_alone(sets, held, window)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
