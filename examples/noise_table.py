"""Fit the noise-level function of real cameras from the PolyU and CC15 (mean image, noisy shot) pairs.

For every camera and ISO the pairs are pooled and :meth:`camdegrade.effects.Noise.fit` estimates the variance
``a · I + b`` of the noise in linear light. The table also gives the noise in 8-bit levels at mid-grey (sRGB
128) and says, per camera, whether that noise increases with ISO.

Usage::

    python examples/noise_table.py [REAL_PAIRS_DIR] [--max-pairs N]

``REAL_PAIRS_DIR`` defaults to ``$CAMDEGRADE_REAL_PAIRS`` or ``../shared/data/real-pairs`` beside the checkout.
The data are read in place and never copied.
"""

from __future__ import annotations

import argparse
import csv
import os
from collections import defaultdict
from dataclasses import dataclass
from itertools import pairwise
from pathlib import Path

import torch

from camdegrade.effects import Noise
from camdegrade.functional import linear_to_srgb, srgb_to_linear
from camdegrade.io import read_image

NOISE_SUBSETS = ("polyu_real_noise", "cc15_nam_real_noise")
#: Mid-grey: sRGB 128/255, about 0.216 in linear light.
MID_GREY = float(srgb_to_linear(torch.tensor(128 / 255)))


@dataclass(frozen=True)
class NoiseRow:
    subset: str
    camera: str
    iso: int
    pairs: int
    a: tuple[float, float, float]
    b: tuple[float, float, float]

    @property
    def sigma_mid_grey(self) -> float:
        """Noise standard deviation at mid-grey in 8-bit sRGB levels, averaged over channels."""
        sigma = (torch.tensor(self.a) * MID_GREY + torch.tensor(self.b)).sqrt()
        slope = (linear_to_srgb(torch.tensor(MID_GREY + 1e-4)) - linear_to_srgb(torch.tensor(MID_GREY))) / 1e-4
        return float(sigma.mean() * slope * 255)


def default_real_pairs_dir() -> Path:
    default = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real-pairs"
    return Path(os.environ.get("CAMDEGRADE_REAL_PAIRS") or default)


def noise_groups(root: Path) -> dict[tuple[str, str, int], list[tuple[Path, Path]]]:
    """``(subset, camera, iso) → [(clean, captured), ...]`` from ``manifest.csv``, for the noise subsets."""
    groups: dict[tuple[str, str, int], list[tuple[Path, Path]]] = defaultdict(list)
    with open(root / "manifest.csv", newline="") as handle:
        for row in csv.DictReader(handle):
            if row["subset"] in NOISE_SUBSETS and row["iso"]:
                key = (row["subset"], row["camera"], int(row["iso"]))
                groups[key].append((root / row["clean_path"], root / row["degraded_path"]))
    return dict(sorted(groups.items()))


def _centre(image: torch.Tensor, crop: int | None) -> torch.Tensor:
    if crop is None:
        return image
    height, width = image.shape[-2:]
    top, left = max(0, (height - crop) // 2), max(0, (width - crop) // 2)
    return image[:, top : top + crop, left : left + crop]


def fit_group(paths: list[tuple[Path, Path]], crop: int | None = None, max_pixels: int | None = 100_000) -> Noise:
    """The noise stage fitted on one camera/ISO: all its pairs pooled (optionally centre-cropped)."""
    sources = [_centre(read_image(clean), crop).float() / 255 for clean, _ in paths]
    targets = [_centre(read_image(captured), crop).float() / 255 for _, captured in paths]
    return Noise.fit(sources, targets, rows=False, max_pixels=max_pixels)


def noise_table(
    root: Path, max_pairs: int | None = None, crop: int | None = None, max_pixels: int | None = 100_000
) -> list[NoiseRow]:
    rows = []
    for (subset, camera, iso), paths in noise_groups(root).items():
        chosen = paths[:max_pairs] if max_pairs else paths
        noise = fit_group(chosen, crop, max_pixels)
        a, b = tuple(noise.a.tolist()), tuple(noise.b.tolist())
        rows.append(NoiseRow(subset, camera, iso, len(chosen), a, b))  # type: ignore[arg-type]
    return rows


def monotone_in_iso(rows: list[NoiseRow]) -> dict[tuple[str, str], bool]:
    """Per (subset, camera) with two or more ISOs: does mid-grey noise increase with ISO?"""
    by_camera: dict[tuple[str, str], list[NoiseRow]] = defaultdict(list)
    for row in rows:
        by_camera[(row.subset, row.camera)].append(row)
    result = {}
    for key, camera_rows in by_camera.items():
        if len(camera_rows) > 1:
            ordered = sorted(camera_rows, key=lambda row: row.iso)
            result[key] = all(lo.sigma_mid_grey < hi.sigma_mid_grey for lo, hi in pairwise(ordered))
    return result


def format_table(rows: list[NoiseRow]) -> str:
    header = (
        f"{'subset':<20} {'camera':<15} {'ISO':>6} {'pairs':>5}  "
        f"{'a (R,G,B) ×1e-3':<20} {'b (R,G,B) ×1e-6':<22} {'σ@128 (8-bit)':>13}"
    )
    lines = [header, "-" * len(header)]
    for row in rows:
        a = ",".join(f"{value * 1e3:.2f}" for value in row.a)
        b = ",".join(f"{value * 1e6:.1f}" for value in row.b)
        lines.append(
            f"{row.subset:<20} {row.camera:<15} {row.iso:>6} {row.pairs:>5}  "
            f"{a:<20} {b:<22} {row.sigma_mid_grey:>13.2f}"
        )
    lines.append("")
    for (subset, camera), increasing in monotone_in_iso(rows).items():
        lines.append(f"{subset}/{camera}: noise {'increases' if increasing else 'does NOT increase'} with ISO")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("root", nargs="?", type=Path, default=None, help="the real-pairs folder")
    parser.add_argument("--max-pairs", type=int, default=None, help="at most this many pairs per camera/ISO")
    parser.add_argument("--crop", type=int, default=None, help="fit on centre crops of this size (faster)")
    args = parser.parse_args(argv)
    root = args.root or default_real_pairs_dir()
    if not (root / "manifest.csv").is_file():
        parser.error(f"no manifest.csv in {root}; pass the real-pairs folder or set CAMDEGRADE_REAL_PAIRS")
    print(format_table(noise_table(root, args.max_pairs, args.crop)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
