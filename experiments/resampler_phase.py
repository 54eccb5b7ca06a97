"""The sensor grid's phase in the gradient energy: captures of a foreign camera against its fitted profile.

A camera that samples fewer pixels than it outputs and upsamples them leaves its grid in the images: the squared
luma difference between neighbours depends on where the pair sits on the sensor grid (across a sensor sample's
centre, or between two). On the held-out pairs of ``bench/bench_foreign_fit.py`` this prints, per grid phase, the
mean squared horizontal and vertical luma difference over its mean (1.0 everywhere: no grid), for the clean
images, the captures and each profile given (sampled with seed 0, 8-bit). A texture cannot fake it and a
shift-invariant filter cannot make it.

    OMP_NUM_THREADS=1 .venv/bin/python experiments/resampler_phase.py webcam PROFILE.safetensors [MORE ...]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "bench"), str(ROOT / "tests")]

from foreign_bench import held_out_pairs  # noqa: E402

from camdegrade._support.pixels import unit_to_bytes  # noqa: E402
from camdegrade.profile import load_profile  # noqa: E402
from foreign_cameras import camera  # noqa: E402


def phase_energy(images: list[torch.Tensor], period: int) -> tuple[list[float], list[float]]:
    """Mean squared horizontal and vertical luma differences at each grid phase, over their mean."""
    across, down = torch.zeros(period, dtype=torch.float64), torch.zeros(period, dtype=torch.float64)
    for image in images:
        luma = image.double().mean(0)
        dx, dy = (luma[:, 1:] - luma[:, :-1]) ** 2, (luma[1:] - luma[:-1]) ** 2
        for phase in range(period):
            across[phase] += dx[:, phase::period].mean()
            down[phase] += dy[phase::period].mean()
    return (across / across.mean()).tolist(), (down / down.mean()).tolist()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("camera")
    parser.add_argument("profiles", nargs="+")
    parser.add_argument("--period", type=int, default=2, help="the sensor grid's period in output pixels")
    parser.add_argument("--pairs", type=int, default=24)
    args = parser.parse_args()
    pairs = held_out_pairs(camera(args.camera), args.pairs, 128)
    cleans = [clean.float() / 255 for clean, _ in pairs]
    rows = {"clean": [clean * 255 for clean in cleans], "capture": [captured.float() for _, captured in pairs]}
    for path in args.profiles:
        simulated = load_profile(path).simulate(cleans, 0)
        label = f"{len(rows) - 1}: {Path(path).parent.parent.name}/{Path(path).name}"
        rows[label] = [unit_to_bytes(image).float() for image in simulated]
    print(f"{args.camera}, {len(pairs)} held-out pairs of 128², grid period {args.period}: across | down")
    for label, images in rows.items():
        across, down = phase_energy(images, args.period)
        shown = " ".join(f"{v:.3f}" for v in across) + " | " + " ".join(f"{v:.3f}" for v in down)
        print(f"{label:52s} {shown}")


if __name__ == "__main__":
    main()
