"""Are the iPhone's strong straight edges displaced as its texture is? On the 16 held-out City100 scenes, per
segment of 24 columns (rows too, transposed) where the clean image has one strong edge across the segment (luma
gradient at least 0.03 within ±1 px of the segment's row, the clean edge's own residual under 0.15 px): each
column's sub-pixel edge position (centroid of the gradient in a band of ±3 px), a line fitted over the segment,
the residual RMS. For the clean image, the capture, the built-in before its jitter (a file) and now.

Usage::

    git show 8cbfe8d:src/camdegrade/profiles/city100-iphonex.safetensors > /tmp/before.safetensors
    OMP_NUM_THREADS=1 .venv/bin/python experiments/edge_straightness_city100.py /tmp/before.safetensors
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

import torch
from fit_city100_default import DEFAULT_DATA, LAST_FITTED_SCENE

from camdegrade import load_profile
from camdegrade._support.pixels import as_unit
from camdegrade.fitting import discover_pairs, filter_pairs, load_pair
from camdegrade.functional.analysis.images import luma

SEGMENT = 24
BAND = 3
MIN_GRADIENT = 0.03
MAX_CLEAN_RESIDUAL = 0.15


def _residual(gradient: torch.Tensor, row: int, left: int) -> float:
    """RMS distance (px) of the edge's per-column centroid from its fitted line."""
    band = gradient[row - BAND : row + BAND + 1, left : left + SEGMENT]
    rows = torch.arange(row - BAND, row + BAND + 1, dtype=torch.float32)[:, None]
    position = (band * rows).sum(0) / band.sum(0).clamp_min(1e-9)
    design = torch.stack([torch.arange(SEGMENT, dtype=torch.float32), torch.ones(SEGMENT)], 1)
    line = design @ torch.linalg.lstsq(design, position[:, None]).solution
    return float((position - line[:, 0]).pow(2).mean().sqrt())


def _segments(gradient: torch.Tensor) -> list[tuple[int, int]]:
    """``(row, left)`` of the segments where one strong edge crosses every column within ±1 px of ``row``."""
    height, width = gradient.shape
    found = []
    for row in range(8, height - 8, 6):
        for left in range(8, width - SEGMENT - 8, SEGMENT):
            band = gradient[row - BAND : row + BAND + 1, left : left + SEGMENT]
            peak = band.argmax(0)
            if (
                bool(((peak >= BAND - 1) & (peak <= BAND + 1)).all())
                and float(band.max(0).values.min()) >= MIN_GRADIENT
            ):
                found.append((row, left))
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("before", type=Path, help="the built-in before its jitter (a profile file)")
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    args = parser.parse_args()
    profiles = {"before": load_profile(args.before), "now": load_profile("city100-iphonex")}
    pairs = filter_pairs(discover_pairs(args.data / "pairs.csv").pairs, subset="city100_iPhoneX")
    held = [pair for pair in pairs if pair.scene > LAST_FITTED_SCENE]
    residuals: dict[str, list[float]] = {name: [] for name in ("clean", "capture", *profiles)}
    for index, pair in enumerate(held):
        clean, capture = (as_unit(image) for image in load_pair(pair))
        images = {"clean": clean, "capture": capture}
        images |= {name: p.simulate([clean], index, eight_bit=True)[0] for name, p in profiles.items()}
        for transposed in (False, True):
            lumas = {name: luma(image).T if transposed else luma(image) for name, image in images.items()}
            gradients = {name: (y[1:] - y[:-1]).abs() for name, y in lumas.items()}
            for row, left in _segments(gradients["clean"]):
                row_residuals = {name: _residual(g, row, left) for name, g in gradients.items()}
                if row_residuals["clean"] < MAX_CLEAN_RESIDUAL:
                    for name, value in row_residuals.items():
                        residuals[name].append(value)
    print(f"{len(residuals['clean'])} edge segments of {SEGMENT} px on {len(held)} held-out scenes")
    for name, values in residuals.items():
        print(
            f"{name}: residual from a straight line, median {statistics.median(values):.3f} px, "
            f"mean {statistics.fmean(values):.3f} px"
        )


if __name__ == "__main__":
    main()
