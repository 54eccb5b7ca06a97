"""Fit and check camera noise on the REAL PolyU, CC15 and SIDD pairs (clean = mean of many frames, real = one frame).

For every camera and ISO (PolyU and CC15 name them; SIDD's crops do not, so SIDD is one group) the images are split
alternately into a fitting half and a checking half. :meth:`camdegrade.effects.Noise.fit` (``estimator="residual"``:
the clean image is a noise-free reference) is fitted on the first half; on the second half, where the clean image is
flat in absolute terms, the fitted noise is compared with the real one: its std per channel and intensity bin, and
its correlation with the neighbour 1 and 2 pixels away, horizontally and vertically. Groups with one image are
fitted (table) but not checked. The ``oracle`` column compares the real noise of the fitting half with the real
noise of the checking half the same way: what a stage reproducing the fitting images' noise exactly would score,
i.e. how much the images' own noise differs from image to image.

Usage::

    python experiments/noise_table.py [REAL_PAIRS_DIR] [--subsets polyu_real_noise ...] [--json PATH]

``REAL_PAIRS_DIR`` defaults to ``$CAMDEGRADE_REAL_PAIRS`` or ``../shared/data/real-pairs`` beside the checkout.
The data are read in place and never copied.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
from collections import defaultdict
from dataclasses import asdict, dataclass
from itertools import pairwise
from pathlib import Path

import torch
from torch import Tensor

from camdegrade._support.pixels import as_unit
from camdegrade.effects import Noise
from camdegrade.functional.analysis.images import flat_mask
from camdegrade.functional.analysis.noise import NoiseSums
from camdegrade.io import read_image

SUBSETS = ("polyu_real_noise", "cc15_nam_real_noise", "sidd_samples")
#: The bar of the check: std per bin within this ratio of the real one, correlations within this difference.
STD_TOLERANCE = 0.15
CORRELATION_TOLERANCE = 0.1


@dataclass
class GroupResult:
    subset: str
    camera: str
    iso: int
    fit_pairs: int
    check_pairs: int
    sigma_mid_grey: float
    flat_pixels: int
    std_ratio: list[list[float | None]]
    correlation_real: list[float]
    correlation_fitted: list[float]
    #: The same per-bin ratio for the *real* noise of the fitting half against the checking half: what a stage that
    #: reproduced the fitting images' noise exactly would score (how much the images' own noise differs).
    oracle_ratio: list[list[float | None]] | None = None

    @property
    def worst_std_error(self) -> float | None:
        errors = [abs(r - 1) for row in self.std_ratio for r in row if r is not None]
        return max(errors) if errors else None

    @property
    def worst_correlation_error(self) -> float | None:
        pairs = [(r, f) for r, f in zip(self.correlation_real, self.correlation_fitted, strict=True) if r == r]
        return max(abs(r - f) for r, f in pairs) if pairs else None


def default_real_pairs_dir() -> Path:
    default = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real-pairs"
    return Path(os.environ.get("CAMDEGRADE_REAL_PAIRS") or default)


def noise_groups(root: Path, subsets: tuple[str, ...] = SUBSETS) -> dict[tuple[str, str, int], list[tuple[Path, Path]]]:
    """``(subset, camera, iso) → [(clean, captured), ...]`` from ``manifest.csv`` (camera/ISO unknown: one group)."""
    groups: dict[tuple[str, str, int], list[tuple[Path, Path]]] = defaultdict(list)
    with open(root / "manifest.csv", newline="") as handle:
        for row in csv.DictReader(handle):
            if row["subset"] in subsets:
                key = (row["subset"], row["camera"] or "unknown", int(row["iso"] or 0))
                groups[key].append((root / row["clean_path"], root / row["degraded_path"]))
    return dict(sorted(groups.items()))


def _load(paths: list[tuple[Path, Path]]) -> tuple[list[Tensor], list[Tensor]]:
    cleans = [as_unit(read_image(clean)) for clean, _ in paths]
    reals = [as_unit(read_image(real)) for _, real in paths]
    return cleans, reals


def _residual_sums(images: list[Tensor], cleans: list[Tensor]) -> NoiseSums:
    total = NoiseSums.zeros()
    for image, clean in zip(images, cleans, strict=True):
        total = total + NoiseSums.measure(image - clean, clean, flat_mask(clean), clipping=image)
    return total


def _simulate(noise: Noise, cleans: list[Tensor], seed: int) -> list[Tensor]:
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        return [noise(c[None], noise.make_params((1, *c.shape), generator))[0] for c in cleans]


def check_group(key: tuple[str, str, int], paths: list[tuple[Path, Path]], seed: int = 0) -> GroupResult:
    """Fit on the even-indexed pairs; compare with the real noise on the odd-indexed ones."""
    subset, camera, iso = key
    fit_paths = paths[::2]
    check_paths = paths[1::2]
    cleans, reals = _load(fit_paths)
    noise = Noise.fit(cleans, reals, estimator="residual", seed=seed)
    if not check_paths:
        check_paths = fit_paths
    held_cleans, held_reals = _load(check_paths)
    real = _residual_sums(held_reals, held_cleans)
    fitted = _residual_sums(_simulate(noise, held_cleans, seed + 1), held_cleans)
    ratio = fitted.std() / real.std()
    oracle = _residual_sums(reals, cleans).std() / real.std()
    return GroupResult(
        subset=subset,
        camera=camera,
        iso=iso,
        fit_pairs=len(fit_paths),
        check_pairs=len(paths[1::2]),
        sigma_mid_grey=round(noise.magnitude(), 3),
        flat_pixels=real.pixels,
        std_ratio=_rounded(ratio),
        correlation_real=[round(float(v), 3) for v in real.correlation().mean(-1).flatten()],
        correlation_fitted=[round(float(v), 3) for v in fitted.correlation().mean(-1).flatten()],
        oracle_ratio=_rounded(oracle),
    )


def _rounded(ratio) -> list[list[float | None]]:
    return [[round(float(r), 3) if torch.isfinite(r) else None for r in row] for row in ratio]


def noise_table(root: Path, subsets: tuple[str, ...] = SUBSETS) -> list[GroupResult]:
    """One row per camera and ISO."""
    return [check_group(key, paths) for key, paths in noise_groups(root, subsets).items()]


def subset_table(root: Path, subsets: tuple[str, ...] = SUBSETS) -> list[GroupResult]:
    """One row per subset: one noise fitted on half of its images, checked on the other half. The halves alternate
    within each camera and ISO, so both hold the same mix of cameras."""
    ordered: dict[str, list[tuple[Path, Path]]] = defaultdict(list)
    for (subset, _, _), paths in noise_groups(root, subsets).items():
        ordered[subset] += paths
    return [check_group((subset, "all", 0), paths) for subset, paths in ordered.items()]


def monotone_in_iso(rows: list[GroupResult]) -> dict[tuple[str, str], bool]:
    """Per (subset, camera) with two or more ISOs: does the noise at mid-grey increase with ISO?"""
    by_camera: dict[tuple[str, str], list[GroupResult]] = defaultdict(list)
    for row in rows:
        by_camera[(row.subset, row.camera)].append(row)
    result = {}
    for key, camera_rows in by_camera.items():
        if len(camera_rows) > 1:
            ordered = sorted(camera_rows, key=lambda row: row.iso)
            result[key] = all(lo.sigma_mid_grey < hi.sigma_mid_grey for lo, hi in pairwise(ordered))
    return result


def format_table(rows: list[GroupResult]) -> str:
    header = (
        f"{'subset':<20} {'camera':<10} {'ISO':>6} {'fit/check':>9} {'σ@128':>6} {'flat px':>9} "
        f"{'bins ±15%':>10} {'oracle':>7} {'worst std':>9} {'corr real h1 h2 v1 v2':>24} {'fitted':>22} {'worst':>6}"
    )
    lines = [header, "-" * len(header)]
    for row in rows:
        ratios = [r for channel in row.std_ratio for r in channel if r is not None]
        within = sum(abs(r - 1) <= STD_TOLERANCE for r in ratios)
        oracle = [r for channel in row.oracle_ratio or [] for r in channel if r is not None]
        oracle_within = f"{sum(abs(r - 1) <= STD_TOLERANCE for r in oracle)}/{len(oracle)}"
        real = " ".join(f"{v:.2f}" for v in row.correlation_real)
        fitted = " ".join(f"{v:.2f}" for v in row.correlation_fitted)
        worst_std = f"{row.worst_std_error:.2f}" if row.worst_std_error is not None else "n/m"
        worst_corr = f"{row.worst_correlation_error:.2f}" if row.worst_correlation_error is not None else "n/m"
        lines.append(
            f"{row.subset:<20} {row.camera:<10} {row.iso:>6} {row.fit_pairs:>4}/{row.check_pairs:<4} "
            f"{row.sigma_mid_grey:>6.2f} {row.flat_pixels:>9,} {within:>4}/{len(ratios):<5} {oracle_within:>7} "
            f"{worst_std:>9} "
            f"{real:>24} {fitted:>22} {worst_corr:>6}"
        )
    lines.append("")
    for (subset, camera), increasing in monotone_in_iso(rows).items():
        lines.append(f"{subset}/{camera}: noise {'increases' if increasing else 'does NOT increase'} with ISO")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("root", nargs="?", type=Path, default=None, help="the real-pairs folder")
    parser.add_argument("--subsets", nargs="+", default=list(SUBSETS), choices=SUBSETS)
    parser.add_argument("--json", type=Path, default=None, help="also write the rows as JSON here")
    parser.add_argument("--per-camera", action="store_true", help="one noise per camera and ISO (default: per subset)")
    args = parser.parse_args(argv)
    root = args.root or default_real_pairs_dir()
    if not (root / "manifest.csv").is_file():
        parser.error(f"no manifest.csv in {root}; pass the real-pairs folder or set CAMDEGRADE_REAL_PAIRS")
    rows = (noise_table if args.per_camera else subset_table)(root, tuple(args.subsets))
    print(format_table(rows))
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps([asdict(row) for row in rows], indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
