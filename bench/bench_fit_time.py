"""Fit time (issue 46): a default fit of 240 simulated pairs of 128² and City100's documented fit, each with its wall
time, its CPU time (all threads: less moved by other jobs than wall time), the time of each fit step, the held-out
PSNR and the fit's image-only critic, and PASS or FAIL against issue 46's targets (≤ 5 min and ≤ 2 min on 2 idle
cores).

- ``default``: ``fit_profile`` with the fast recipe on 240 pairs of 128² of a simulated camera
  (``experiments/simulated_camera_fidelity.py``'s ``dark`` camera by default: sensor noise, exposure, a tone curve;
  dead leaves and flat charts), scored on 64 other pairs (PSNR of the sampled profile, rounded to 8 bits).
- ``city100``: ``experiments/fit_city100_default.py``'s fit (the built-in ``city100-iphonex``'s command): the REAL
  City100 iPhone X pairs of scenes 001–055, scored on scenes 056–070 and 098 (the sampled profile's PSNR); skipped
  without ``../shared/data/real-pairs`` (or ``CAMDEGRADE_REAL_PAIRS``).

The critic is the fit's own (``quality['fidelity']['critic_image_only']``, on its validation pairs). A fit's
numbers are compared with an earlier run's JSON (``--reference``, e.g. the same script run with another checkout's
``src`` first on ``PYTHONPATH``): held-out PSNR within 0.1 dB and the critic's accuracy within its interval. The wall
time is only as good as the machine is idle: the load average is printed beside it. Run from the repo root::

    OMP_NUM_THREADS=2 .venv/bin/python bench/bench_fit_time.py [--fits default city100] [--json out/bench/fit_time.json]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from machine import cpu_description, load_text

import camdegrade.fitting.fit as fit_module
from camdegrade._support.pixels import as_unit
from camdegrade.fitting import FitConfig, PairSet, discover_pairs, filter_pairs, fit_profile, load_pair
from camdegrade.measures.metrics import psnr

ROOT = Path(__file__).resolve().parents[1]
#: Issue 46's targets: wall seconds on 2 idle cores.
TARGETS = {"default": 300.0, "city100": 120.0}
#: The default fit's pairs: training and held-out counts, their seeds (as experiments/simulated_camera_fidelity.py).
DEFAULT_PAIRS, HELD_OUT_PAIRS = 240, 64
PSNR_TOLERANCE_DB = 0.1


class StepClock:
    """Wall and CPU seconds of each fit step and of the closing quality report, by name, while installed."""

    def __init__(self) -> None:
        self.seconds: dict[str, list[float]] = {}

    def timed(self, name: str, call: Callable[[], Any]) -> Any:
        wall, cpu = time.perf_counter(), time.process_time()
        try:
            return call()
        finally:
            spent = [time.perf_counter() - wall, time.process_time() - cpu]
            previous = self.seconds.get(name, [0.0, 0.0])
            self.seconds[name] = [round(previous[0] + spent[0], 1), round(previous[1] + spent[1], 1)]

    def install(self) -> None:
        def run_steps(steps, fit) -> None:
            for step in steps:
                reason = fit.unmet(step)
                if reason is not None:
                    fit.skip(step, reason)
                    continue
                record = self.timed(step.name, lambda step=step: step.run(fit))
                if record is not None:
                    fit.records[step.name] = record

        quality = fit_module.validation_quality
        fit_module.run_steps = run_steps
        fit_module.validation_quality = lambda *args, **kwargs: self.timed("quality", lambda: quality(*args, **kwargs))


def default_fit(camera_name: str, count: int) -> tuple[Callable[[], Any], Callable[[Any], float]]:
    from simulated_camera_fidelity import pairs

    train, held = pairs(camera_name, count, seed=3), pairs(camera_name, HELD_OUT_PAIRS, seed=11)

    def held_out_psnr(profile) -> float:
        cleans = [as_unit(clean) for clean, _ in held]
        sims = profile.simulate(cleans, seed=0, stream="heldout", eight_bit=True)
        return sum(psnr(sim, as_unit(real)) for sim, (_, real) in zip(sims, held, strict=True)) / len(held)

    return lambda: fit_profile(train, FitConfig.recipe("fast")), held_out_psnr


def city100_fit(data: Path) -> tuple[Callable[[], Any], Callable[[Any], float]]:
    from fit_city100_default import DESCRIPTION, LAST_FITTED_SCENE

    pairs = filter_pairs(discover_pairs(data / "pairs.csv").pairs, subset="city100_iPhoneX")
    fitted = [pair for pair in pairs if pair.scene <= LAST_FITTED_SCENE]
    held = [pair for pair in pairs if pair.scene > LAST_FITTED_SCENE]

    def held_out_psnr(profile) -> float:  # each scene seeded by its index, as fit_city100_default.py seeds it
        scores = []
        for index, pair in enumerate(held):
            clean, real = (as_unit(image) for image in load_pair(pair))
            sim = profile.simulate([clean], seed=index, stream="heldout", eight_bit=True)[0]
            scores.append(psnr(sim, real))
        return sum(scores) / len(scores)

    def fit() -> Any:
        return fit_profile(
            PairSet.load(fitted), FitConfig.recipe("fast"), name="city100-iphonex", description=DESCRIPTION
        )

    return fit, held_out_psnr


def run_fit(
    name: str, fit: Callable[[], Any], held_out_psnr: Callable[[Any], float], save: Path | None
) -> dict[str, Any]:
    clock = StepClock()
    clock.install()
    load_before = load_text()
    wall, cpu = time.perf_counter(), time.process_time()
    profile = fit()
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    if save is not None:
        save.mkdir(parents=True, exist_ok=True)
        profile.save(save / f"{name}.safetensors")
    critic = (profile.quality.get("fidelity") or {}).get("critic_image_only") or {}
    return {
        "fit": name,
        "wall_s": round(wall, 1),
        "cpu_s": round(cpu, 1),
        "load": f"{load_before}; after: {load_text()}",
        "steps_wall_cpu_s": clock.seconds,
        "held_out_psnr_db": round(held_out_psnr(profile), 3),
        "validation_profile_psnr_db": profile.quality.get("profile_psnr_db"),
        "critic_image_only": {key: critic.get(key) for key in ("accuracy", "std", "low", "high")},
        "effects": profile.effect_names,
        "best_epoch": profile.fitted.get("best_epoch"),
    }


def verdicts(row: dict[str, Any], reference: dict[str, Any] | None) -> list[str]:
    target = TARGETS[row["fit"]]
    lines = [
        f"{row['fit']}: wall {row['wall_s']:.0f} s (target ≤ {target:.0f} s on 2 idle cores) "
        f"{'PASS' if row['wall_s'] <= target else 'FAIL'}; CPU {row['cpu_s']:.0f} s (all threads); {row['load']}"
    ]
    if reference is None:
        return lines
    shift = row["held_out_psnr_db"] - reference["held_out_psnr_db"]
    low, high = reference["critic_image_only"]["low"], reference["critic_image_only"]["high"]
    accuracy = row["critic_image_only"]["accuracy"]
    critic_ok = accuracy is None if low is None else low <= accuracy <= high
    lines.append(
        f"{row['fit']}: held-out PSNR {row['held_out_psnr_db']:.3f} against {reference['held_out_psnr_db']:.3f} dB "
        f"({shift:+.3f}, within {PSNR_TOLERANCE_DB}) {'PASS' if abs(shift) <= PSNR_TOLERANCE_DB else 'FAIL'}; "
        f"critic {accuracy} against {reference['critic_image_only']['accuracy']} [{low}, {high}] "
        f"{'PASS' if critic_ok else 'FAIL'}; wall {row['wall_s'] / max(reference['wall_s'], 1e-9):.2f}×, "
        f"CPU {row['cpu_s'] / max(reference['cpu_s'], 1e-9):.2f}× the reference's"
    )
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--fits", nargs="+", default=["default", "city100"], choices=sorted(TARGETS))
    parser.add_argument("--camera", default="dark", choices=("soft", "dark"), help="the default fit's camera")
    parser.add_argument("--pairs", type=int, default=DEFAULT_PAIRS, help="the default fit's (fewer: a quick check)")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--reference", type=Path, default=None, help="an earlier run's JSON to compare with")
    parser.add_argument("--save", type=Path, default=None, help="a folder to write each fitted profile to")
    parser.add_argument("--json", type=Path, default=ROOT / "out" / "bench" / "fit_time.json")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    data = Path(os.environ.get("CAMDEGRADE_REAL_PAIRS") or ROOT.parent / "shared" / "data" / "real-pairs")
    print(f"fit time on {cpu_description()}, {args.threads} threads; camdegrade from {fit_module.__file__}")
    reference = {row["fit"]: row for row in json.loads(args.reference.read_text())} if args.reference else {}
    rows = []
    for name in args.fits:
        if name == "city100" and not (data / "pairs.csv").is_file():
            print(f"city100: skipped (no pairs.csv in {data})")
            continue
        fit, held_out_psnr = default_fit(args.camera, args.pairs) if name == "default" else city100_fit(data)
        row = run_fit(name, fit, held_out_psnr, args.save)
        rows.append(row)
        print(json.dumps(row), flush=True)
        print("\n".join(verdicts(row, reference.get(name))), flush=True)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
