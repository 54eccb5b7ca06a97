"""Time to a good network: the paper's recipe against camdegrade's fast one, on REAL City100 pairs and on a
simulated camera, with the same training code, machine and seed.

For each data set both recipes train a network (:func:`camdegrade.fitting.fit_network`) on the same training pairs
and choose their best epoch on the same validation pairs; the paper's recipe with the crops per pair its built-in
profile was fitted with, the fast one as it is. The paper's best validation PSNR is the bar; the table gives each
fit's wall time, its best validation PSNR and when it first came within 0.1 dB of that bar.

- ``city100``: the REAL City100 iPhone X pairs (``../shared/data/real-pairs``), train scenes 001–047, validation
  048–055 (as ``experiments/fit_city100.py``); the paper's recipe with 4 crops of 128² per pair and epoch;
- ``simulated``: random 256² crops of scikit-image photographs captured by the ``lowcost-robot`` virtual camera
  (as ``experiments/fit_lowcost_robot_sim.py``), validation scene ``rocket``; the paper's recipe with 3 crops.

Usage (from the repo root; about 10 minutes on 2 cores with native bfloat16)::

    .venv/bin/python experiments/recipe_comparison.py [--data city100 simulated] [--json out/recipes.json]
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch

from camdegrade.fitting import FitConfig, discover_pairs, load_pair
from camdegrade.fitting.network.training import EpochResult, fit_network, training_dtype
from camdegrade.pairs.pairset import ImagePair

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fit_city100 import DEFAULT_DATA, HELD_OUT, VALIDATION, city100_iphone_pairs, load

#: Within this many dB of the paper recipe's best validation PSNR counts as reaching it.
TOLERANCE_DB = 0.1


@dataclass
class RecipeRun:
    recipe: str
    config: dict
    seconds: float = 0.0
    best_val_psnr: float = float("nan")
    best_epoch: int = 0
    epochs_run: int = 0
    #: (epoch, seconds since the start, validation PSNR) after every epoch.
    curve: list[tuple[int, float, float]] = field(default_factory=list)

    def seconds_to(self, target: float) -> float | None:
        """Seconds until the validation PSNR first reached ``target`` (None: never)."""
        return next((seconds for _, seconds, score in self.curve if score >= target), None)


def city100_data(data: Path) -> tuple[list[ImagePair], list[ImagePair], int]:
    scenes = city100_iphone_pairs(data)
    train = load(scenes, lambda s: s not in HELD_OUT and s not in VALIDATION)
    val = load(scenes, lambda s: s in VALIDATION)
    return train, val, 4


def simulated_data(work: Path, seed: int) -> tuple[list[ImagePair], list[ImagePair], int]:
    from fit_lowcost_robot_sim import TRAIN_IMAGES, make_pairs

    manifest = make_pairs(TRAIN_IMAGES, 8, 256, work, seed)
    pairs = discover_pairs(manifest).pairs
    train = [load_pair(pair) for pair in pairs if pair.scene != "rocket"]
    val = [load_pair(pair) for pair in pairs if pair.scene == "rocket"]
    return train, val, 3


def run_recipe(recipe: str, train, val, seed: int, **overrides) -> RecipeRun:
    config = FitConfig.recipe(recipe, seed=seed, **overrides)
    run = RecipeRun(recipe, config.training_dict())
    started = time.perf_counter()

    def record(result: EpochResult) -> None:
        run.curve.append((result.epoch, round(time.perf_counter() - started, 2), round(result.val_psnr, 4)))
        print(f"  {recipe:5s} epoch {result.epoch:3d}  lr {result.lr:.5f}  val {result.val_psnr:.3f} dB", flush=True)

    _, history = fit_network(train, val, config, callback=record)
    run.seconds = round(time.perf_counter() - started, 1)
    best = max(history, key=lambda r: r.val_psnr)
    run.best_val_psnr, run.best_epoch, run.epochs_run = round(best.val_psnr, 4), best.epoch, len(history)
    return run


def compare(name: str, train, val, crops_per_pair: int, seed: int, fast_overrides: dict) -> dict:
    print(f"{name}: {len(train)} training pairs, {len(val)} validation pairs", flush=True)
    paper = run_recipe("paper", train, val, seed, crops_per_pair=crops_per_pair)
    fast = run_recipe("fast", train, val, seed, **fast_overrides)
    bar = paper.best_val_psnr - TOLERANCE_DB
    return {
        "data": name,
        "paper": paper.__dict__,
        "fast": fast.__dict__,
        "bar_db": round(bar, 4),
        "fast_reaches_bar": fast.best_val_psnr >= bar,
        "fast_seconds_to_bar": fast.seconds_to(bar),
        "time_ratio": round(fast.seconds / paper.seconds, 3),
    }


def format_rows(rows: list[dict]) -> str:
    header = (
        f"{'data':10s} {'recipe':6s} {'epochs':>6s} {'best ep':>7s} {'best val dB':>11s} {'wall s':>7s} "
        f"{'to bar s':>8s} {'time / paper':>12s}"
    )
    lines = [header, "-" * len(header)]
    for row in rows:
        for recipe in ("paper", "fast"):
            run = row[recipe]
            to_bar = RecipeRun(**run).seconds_to(row["bar_db"])
            ratio = run["seconds"] / row["paper"]["seconds"]
            lines.append(
                f"{row['data']:10s} {recipe:6s} {run['epochs_run']:>6d} {run['best_epoch']:>7d} "
                f"{run['best_val_psnr']:>11.3f} {run['seconds']:>7.1f} "
                f"{to_bar if to_bar is not None else float('nan'):>8.1f} {ratio:>12.2f}"
            )
        to_bar = row["fast_seconds_to_bar"]
        share = to_bar / row["paper"]["seconds"] if to_bar is not None else float("nan")
        verdict = "PASS" if to_bar is not None and share <= 0.25 else "FAIL"
        lines.append(
            f"  {verdict}: fast reached {row['bar_db']:.3f} dB (paper's best − {TOLERANCE_DB}) after {share:.2f}× the "
            f"paper's wall time (target ≤ 0.25); its whole fit took {row['time_ratio']:.2f}×, best "
            f"{row['fast']['best_val_psnr']:.3f} dB"
        )
    return "\n".join(lines)


def _override(text: str) -> tuple[str, float | int | str]:
    key, _, value = text.partition("=")
    for kind in (int, float):
        try:
            return key, kind(value)
        except ValueError:
            continue
    return key, value


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", nargs="+", default=["city100", "simulated"], choices=("city100", "simulated"))
    parser.add_argument("--real-pairs", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--fast", nargs="*", default=[], metavar="KEY=VALUE", help="change the fast recipe (trials)")
    parser.add_argument("--json", type=Path, default=Path("out/recipes.json"))
    args = parser.parse_args(argv)
    overrides = dict(_override(text) for text in args.fast)
    dtype = training_dtype(FitConfig().precision, torch.device("cpu"))
    print(f"machine: {platform.processor() or platform.machine()}, {torch.get_num_threads()} threads, training {dtype}")
    rows = []
    with tempfile.TemporaryDirectory(prefix="camdegrade-recipes-") as work:
        for name in args.data:
            if name == "city100":
                train, val, crops = city100_data(args.real_pairs)
            else:
                train, val, crops = simulated_data(Path(work), args.seed)
            rows.append(compare(name, train, val, crops, args.seed, overrides))
    print(format_rows(rows))
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"fast_overrides": overrides, "rows": rows}, indent=1) + "\n")
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
