"""The trace of a digital upscale, read from images alone: spectral coherence at the sensor's period.

For each set of images, :func:`camdegrade.measures.traces.resampling.resampling_trace`'s coherence at 1/2, 1/3 and 1/4
cycles/pixel, the null (median at control frequencies) and the period found. Sets: 24 dead-leaves images of 128²
(8-bit) as they are, upscaled from 1/2, 1/3 and 1/4 of their resolution, blurred (σ 1.2) and with sensor noise;
the captures of the two simulated cameras of ``experiments/simulated_camera_fidelity.py`` (soft: a 2× resolution loss;
dark: none) and of the ``lowcost-robot`` virtual camera (half resolution); dead leaves blurred and compressed
hard (JPEG's 8×8 grid repeats at 1/4 and 1/2 too), and upscaled then compressed; and, where
``../shared/data/real-pairs`` is present, the first 24 captures and clean images of each real subset. Run from
the repo root::

    OMP_NUM_THREADS=2 .venv/bin/python experiments/sensor_resolution.py [--json out/sensor_resolution.json]
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

import torch
from noise_table import default_real_pairs_dir
from simulated_camera_fidelity import pairs as simulated_pairs

from camdegrade._support.pixels import unit_to_bytes
from camdegrade.effects import JPEG, Blur, Noise
from camdegrade.functional import resolution_image
from camdegrade.io import read_image
from camdegrade.measures.traces.resampling import resampling_trace
from camdegrade.sim import VirtualCamera
from camdegrade.synthetic import dead_leaves_images

COUNT = 24


def generated_sets() -> dict[str, list[torch.Tensor]]:
    leaves = [image.float() / 255 for image in dead_leaves_images(COUNT, 128, seed=5)]
    noise = Noise(a=0.01, b=1e-4)
    generator = torch.Generator().manual_seed(0)
    sets = {"dead leaves": leaves}
    for period in (2, 3, 4):
        sets[f"dead leaves upscaled from 1/{period}"] = [resolution_image(x, 1 / period) for x in leaves]
    sets["dead leaves blurred (sigma 1.2)"] = [Blur(1.2)(x[None])[0] for x in leaves]
    sets["dead leaves with sensor noise"] = [
        noise(x[None], noise.make_params((1, *x.shape), generator))[0] for x in leaves
    ]
    codec = JPEG(20)
    sets["dead leaves blurred (sigma 2), JPEG quality 20"] = [codec(Blur(2.0)(x[None]))[0] for x in leaves]
    sets["dead leaves upscaled from 1/2, JPEG quality 75"] = [
        JPEG(75)(resolution_image(x, 0.5)[None])[0] for x in leaves
    ]
    sets = {name: [unit_to_bytes(x) for x in images] for name, images in sets.items()}
    for camera in ("soft", "dark"):
        sets[f"{camera} camera captures"] = [captured for _, captured in simulated_pairs(camera, COUNT, seed=3)]
    robot = VirtualCamera.from_preset("lowcost-robot")
    with torch.no_grad():
        sets["lowcost-robot captures"] = [
            robot(clean, generator=torch.Generator().manual_seed(index))
            for index, clean in enumerate(dead_leaves_images(COUNT, 128, seed=7))
        ]
    return sets


def real_sets(root: Path) -> dict[str, list[torch.Tensor]]:
    manifest = root / "pairs.csv"
    if not manifest.exists():
        return {}
    groups: dict[str, list[dict[str, str]]] = {}
    for row in csv.DictReader(manifest.open()):
        groups.setdefault(row["subset"], []).append(row)
    sets = {}
    for subset, rows in groups.items():
        for side in ("captured", "clean"):
            sets[f"{subset} {side}"] = [read_image(root / row[side]) for row in rows[:COUNT]]
    return sets


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    rows = []
    print("| images | n | size | 1/2 | 1/3 | 1/4 | null | JPEG grid | period found |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, images in {**generated_sets(), **real_sets(default_real_pairs_dir())}.items():
        trace = resampling_trace(images)
        size = "×".join(str(side) for side in images[0].shape[-2:])
        values = " | ".join(f"{trace.coherence[period]:.3f}" for period in (2, 3, 4))
        found = f"1/{trace.period}" if trace.period else "none"
        print(
            f"| {name} | {len(images)} | {size} | {values} | {trace.null:.3f} | {trace.codec:.3f} | {found} |",
            flush=True,
        )
        rows.append({"images": name, **trace.to_dict()})
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
