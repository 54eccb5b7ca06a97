"""What the foreign diagnosis bench's base profiles misfit on their own (issue 42, item 3's remaining misses).

Two measurements on the base fits that ``bench/bench_foreign_diagnosis.py`` caches (``OUT/fits/BASE-64x128``):

- **tone**: the capture minus the profile's simulation (sampled, seed 0), in levels, per channel and per tenth of
  the clean value, and the least-squares colour gain ``real ≈ A · sim``, on the fit's own training pairs, the fit's
  held-out pairs and the diagnosis pairs (scene seeds 101, 202, 303): a misfit the fit leaves on its own training
  pairs is the profile's, not a failure to generalise.
- **noise**: on the diagnosis' held-out half of a scenario's pairs (split by scene, seed 0, as ``diagnose`` splits
  them), the flat-pixel noise std of the captures and of the profile per clean-value bin, and the bins' scale (NaN:
  left out of every gap, :func:`camdegrade.measures.gap.measurement_scale`).

Run from the repo root::

    PYTHONPATH=src:tests OMP_NUM_THREADS=1 .venv/bin/python experiments/foreign_base_misfit.py tone webcam --out /tmp/fd
    PYTHONPATH=src:tests OMP_NUM_THREADS=1 .venv/bin/python experiments/foreign_base_misfit.py noise phone --out /tmp/fd
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

from foreign_bench import (
    DIAGNOSIS_SEED,
    HELD_OUT_SEED,
    OTHER_PHOTOS,
    TRAIN_PHOTOS,
    TRAIN_SEED,
    make_pairs,
)

from camdegrade import load_profile
from camdegrade.diagnose.heldout import Baseline, HeldOut
from camdegrade.pairs.pairset import PairSet
from foreign_cameras import SCENARIOS

SETS = (("training", TRAIN_SEED, TRAIN_PHOTOS), ("fit held-out", HELD_OUT_SEED, OTHER_PHOTOS))
DIAGNOSIS = ("diagnosis", DIAGNOSIS_SEED, OTHER_PHOTOS)


def tone(profile, base: str, pairs: int) -> None:
    bins = np.linspace(0.0, 1.0, 11)
    for label, seed, photos in (*SETS, DIAGNOSIS):
        made = make_pairs(SCENARIOS[base]["control"].camera(), pairs, 128, seed, photos)
        cleans = [clean.float() / 255 for clean, _ in made]
        reals = [real.float() / 255 for _, real in made]
        sims = profile.simulate(cleans, 0)
        clean, real, sim = (torch.cat([x.reshape(3, -1) for x in xs], 1).numpy() for xs in (cleans, reals, sims))
        gain = np.diag(np.linalg.lstsq(sim.T, real.T, rcond=None)[0].T)
        print(f"{label}: real ≈ A·sim, diagonal {[round(float(g), 3) for g in gain]}; real − sim (levels) per tenth:")
        for channel, name in enumerate("RGB"):
            where = np.digitize(clean[channel], bins) - 1
            rows = [(real - sim)[channel][where == b] for b in range(10)]
            print(f"  {name}", [round(float(r.mean()) * 255, 1) if r.size > 100 else None for r in rows])


def noise(profile, base: str, scenario: str, pairs: int) -> None:
    made = make_pairs(SCENARIOS[base][scenario].camera(), pairs, 128, DIAGNOSIS_SEED, OTHER_PHOTOS)
    _, held_set = PairSet.load(made).split(0.5, 0)
    held = HeldOut.build(held_set.unit_pairs(), 0, "held-out")
    baseline = Baseline.measure(held, profile)
    print(f"{len(held_set)} held-out pairs; noise family score {baseline.families['noise']:.2f}")
    for label, values in (("real", held.real.values()["noise"]), ("sim", baseline.stats.values()["noise"])):
        print(f"  {label} std per bin:", _rounded(values, 1))
    print("  scale per bin:", _rounded(held.scale["noise"], 3))


def _rounded(values: torch.Tensor, digits: int) -> list[list[float]]:
    return [[round(float(v), digits) for v in row] for row in values.reshape(3, -1)]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("what", choices=("tone", "noise"))
    parser.add_argument("base")
    parser.add_argument("--scenario", default="noise-after")
    parser.add_argument("--pairs", type=int, default=24)
    parser.add_argument("--out", type=Path, default=Path("/tmp/foreign"))
    args = parser.parse_args()
    torch.set_num_threads(1)
    profile = load_profile(args.out / "fits" / f"{args.base}-64x128.safetensors")
    if args.what == "tone":
        tone(profile, args.base, args.pairs)
    else:
        noise(profile, args.base, args.scenario, args.pairs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
