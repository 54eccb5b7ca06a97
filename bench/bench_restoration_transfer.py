"""The restoration-transfer test (issue 43): does a restorer trained on a profile's simulation of clean images do
as well on the camera's real captures as one trained on the camera's real pairs?

Plain script, not a test. The same small restorer (``restorer.py``: a residual CNN, the same initialisation and the
same training windows for every row of a seed) is trained once per row and seed on windows of the City100 iPhone X
training scenes 001–055, where only the degraded input differs by row (``restoration_rows.py``: the real captures,
the built-in ``city100-iphonex``, a blur + colour map, the unpaired profile, the clean image itself), and is tested
on the REAL held-out captures 056–070 and 098: restore the capture, score it against the clean image with an
alignment-tolerant PSNR (``aligned_scoring.py``: each 96² tile moved by its own sub-pixel shift first, so that the
captures' misregistration costs no row anything). The capture itself is scored the same way; a row's gain is its
PSNR less the capture's, and its closure ``(row − colour map) / (real − colour map)``. Beside it, where in the
spectrum each restorer's output falls short of the clean image (``restoration_evidence.py``), what every row trains
on against the capture on the training scenes, and crops (clean | capture | built-in simulation | restored by the
real row | restored by the built-in row).

The trainings run in ``--workers`` processes of one thread each. Needs ``../shared/data/real-pairs`` beside the
checkout (or ``CAMDEGRADE_REAL_PAIRS``); skipped without it. Run from the repo root::

    .venv/bin/python bench/bench_restoration_transfer.py            # writes out/bench/restoration_transfer.json
    .venv/bin/python bench/bench_restoration_transfer.py --quick    # one seed, few steps, 3 held-out scenes
    .venv/bin/python bench/bench_restoration_transfer.py --seeds 1 --json s1.json   # one seed a run, then
    .venv/bin/python bench/bench_restoration_transfer.py --combine s0.json s1.json s2.json   # merged

The unpaired profile is read from ``--unpaired`` (default ``out/bench/city100-iphonex-unpaired.safetensors``) and
fitted there once when the file is absent (not in ``--quick``, which then leaves its row out).

References:
    C. Chen, Z. Xiong, X. Tian, Z.-J. Zha, F. Wu, "Camera Lens Super-Resolution", CVPR 2019 (City100).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import platform
import statistics
import sys
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import torch
from aligned_scoring import unaligned_psnr
from machine import run_facts, write_json
from noise_gap_evidence import write_panel
from residual_cnn import train_network
from restoration_evidence import BANDS, added, band_profile, crop_2x, format_bands, textured_window
from restoration_rows import BUILT_IN, HELD_OUT, ROWS, TRAINING, Row, load_city100, make_rows, missing_scenes
from restorer import Restorer, restore, score

REPOSITORY = Path(__file__).resolve().parents[1]
DEFAULT_DATA = REPOSITORY.parent / "shared" / "data" / "real-pairs"
DEFAULT_UNPAIRED = REPOSITORY / "out" / "bench" / "city100-iphonex-unpaired.safetensors"
#: Held-out scenes shown in the panel (062: text; 098: a fine railing) and scored in ``--quick``.
SHOWN = ("060", "062", "098")
TRAIN_STREAM = "restore-train"
QUICK = {"steps": 150, "seeds": [0], "compare": 4}
#: The rows whose restored crops the panel shows.
PANEL = ("real", "built_in")


# -- the jobs (run in the worker processes) --------------------------------------------------------------------------


def _one_thread() -> None:
    torch.set_num_threads(1)


def train_job(root: Path, held_out: tuple[str, ...], row: Row, seed: int, config: Restorer) -> dict[str, Any]:
    """A restorer trained on ``row``'s degraded training images: its held-out PSNR per image, band sums, the
    restored crops of :data:`SHOWN` and the CPU seconds."""
    started = time.process_time()
    data = load_city100(root, held_out)
    degraded = row.degraded(data.train_clean, data.train_captured, seed, TRAIN_STREAM)
    model = train_network(data.train_clean, degraded, config, seed)
    outputs = [restore(model, capture, config.fold) for capture in data.test_captured]
    psnr, bands = score(outputs, data.test_clean)
    crops = {
        scene: crop_2x(outputs[index], textured_window(data.test_clean[index]))
        for index, scene in enumerate(data.test_scenes)
        if scene in SHOWN
    }
    return {"psnr": psnr, "bands": bands, "crops": crops, "cpu": time.process_time() - started}


def reference_job(root: Path, held_out: tuple[str, ...], rows: dict[str, Row], compared: int) -> dict[str, Any]:
    """The held-out captures scored as a restorer's output; on the first ``compared`` training scenes, each row's
    training input (seed 0) against the clean image and against the capture; the crops of the clean images, the
    captures and the built-in's simulation of :data:`SHOWN`."""
    started = time.process_time()
    data = load_city100(root, held_out)
    psnr, bands = score(data.test_captured, data.test_clean)
    unaligned = [unaligned_psnr(x, c) for x, c in zip(data.test_captured, data.test_clean, strict=True)]
    cleans, captures = data.train_clean[:compared], data.train_captured[:compared]
    inputs = {}
    for name, row in rows.items():
        if row.source == "clean":  # the clean image itself: nothing to compare
            continue
        images = row.degraded(cleans, captures, 0, TRAIN_STREAM)
        aligned, sums = score(images, cleans)
        plain = statistics.fmean(unaligned_psnr(x, c) for x, c in zip(images, cleans, strict=True))
        inputs[name] = {"aligned_psnr_db": statistics.fmean(aligned), "psnr_db": plain, "bands": sums}
    crops = {}
    for index, scene in enumerate(data.test_scenes):
        if scene in SHOWN:
            clean, window = data.test_clean[index], textured_window(data.test_clean[index])
            simulated = rows["built_in"].degraded([clean], [data.test_captured[index]], 0, "restore-show")[0]
            crops[scene] = [crop_2x(image, window) for image in (clean, data.test_captured[index], simulated)]
    return {
        "psnr": psnr,
        "unaligned_psnr": unaligned,
        "bands": bands,
        "inputs": inputs,
        "crops": crops,
        "cpu": time.process_time() - started,
    }


# -- the run ---------------------------------------------------------------------------------------------------------


def run(
    root: Path,
    held_out: tuple[str, ...],
    rows: dict[str, Row],
    config: Restorer,
    seeds: Sequence[int],
    options: argparse.Namespace,
) -> dict[str, Any]:
    """Every row trained with every seed, and the reference job, ``options.workers`` processes at a time."""
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(options.workers, mp_context=context, initializer=_one_thread) as pool:
        reference = pool.submit(reference_job, root, held_out, rows, min(options.compare, len(TRAINING)))
        jobs = {
            (name, seed): pool.submit(train_job, root, held_out, row, seed, config)
            for seed in seeds
            for name, row in rows.items()
        }
        trained = {}
        for (name, seed), job in jobs.items():
            trained[name, seed] = job.result()
            mean = statistics.fmean(trained[name, seed]["psnr"])
            print(f"  seed {seed} {name}: {mean:.3f} dB ({trained[name, seed]['cpu']:.0f} s CPU)", file=sys.stderr)
        captured = reference.result()
    return {"trained": trained, "reference": captured}


def summarise(psnr: dict[str, list[list[float]]], capture: list[float], unaligned: list[float]) -> dict[str, Any]:
    """Per row, the gain over the capture (dB) per seed, its mean and spread (max − min), and the closure
    ``(row − colour map) / (real − colour map)`` on the means and per seed; the capture's PSNR, aligned and not."""
    base = statistics.fmean(capture)
    gains = {name: [statistics.fmean(images) - base for images in seeds] for name, seeds in psnr.items()}
    mean = {name: statistics.fmean(values) for name, values in gains.items()}
    summary: dict[str, Any] = {
        "capture_psnr_db": base,
        "capture_unaligned_psnr_db": statistics.fmean(unaligned),
        "gain_db": gains,
        "mean": mean,
        "spread": {name: max(values) - min(values) for name, values in gains.items()},
    }
    if "real" in gains and "colour_map" in gains:
        span = mean["real"] - mean["colour_map"]
        summary["closure"] = {name: (mean[name] - mean["colour_map"]) / span for name in gains}
        summary["closure_per_seed"] = {
            name: [(g - c) / (r - c) for g, c, r in zip(values, gains["colour_map"], gains["real"], strict=True)]
            for name, values in gains.items()
        }
    return summary


def format_table(summary: dict[str, Any], seeds: Sequence[int]) -> str:
    lines = [
        f"| row | gain dB over the capture (mean of {len(seeds)} seeds) | spread | per seed | closure | per seed |",
        "|---|---:|---:|---|---:|---|",
    ]
    closure = summary.get("closure", {})
    for name, values in summary["gain_db"].items():
        per_seed = " / ".join(f"{v:+.2f}" for v in values)
        close = f"{closure[name]:.2f}" if name in closure else ""
        close_seeds = " / ".join(f"{v:.2f}" for v in summary["closure_per_seed"][name]) if name in closure else ""
        lines.append(
            f"| {name} | {summary['mean'][name]:+.2f} | {summary['spread'][name]:.2f} | {per_seed} | {close} | "
            f"{close_seeds} |"
        )
    lines.append(
        f"| (the capture itself) | {summary['capture_psnr_db']:.2f} dB ({summary['capture_unaligned_psnr_db']:.2f} "
        "not aligned) | | | | |"
    )
    return "\n".join(lines)


def format_inputs(inputs: dict[str, dict[str, Any]], compared: int) -> str:
    lines = [
        f"| training input ({compared} training scenes, seed 0) | PSNR to clean, aligned | not aligned |",
        "|---|---:|---:|",
    ]
    for name, measured in inputs.items():
        lines.append(f"| {name} | {measured['aligned_psnr_db']:.2f} | {measured['psnr_db']:.2f} |")
    return "\n".join(lines)


def report(outcome: dict[str, Any], names: Sequence[str], seeds: Sequence[int], compared: int) -> dict[str, Any]:
    """Print the tables; the record for the JSON."""
    trained, reference = outcome["trained"], outcome["reference"]
    psnr = {name: [trained[name, seed]["psnr"] for seed in seeds] for name in names}
    summary = summarise(psnr, reference["psnr"], reference["unaligned_psnr"])
    print(format_table(summary, seeds))
    outputs = {"capture": band_profile(reference["bands"], reference["bands"])}
    for name in names:
        outputs[name] = band_profile(added([trained[name, seed]["bands"] for seed in seeds]), reference["bands"])
    print(f"\nRestored held-out captures, per band ({' / '.join(BANDS)} cycles/px):\n")
    print(format_bands(outputs, ("log2_output_over_clean", "error_gain_db", "coherence")))
    inputs = reference["inputs"]
    print("\n" + format_inputs(inputs, compared))
    profiles = {name: band_profile(measured["bands"], inputs["real"]["bands"]) for name, measured in inputs.items()}
    print(f"\nTraining inputs, per band ({' / '.join(BANDS)} cycles/px):\n")
    print(format_bands(profiles, ("log2_output_over_capture", "coherence")))
    return {
        "psnr_db": psnr,
        "capture_psnr_db": reference["psnr"],
        "summary": summary,
        "output_bands": outputs,
        "training_inputs": {name: {**inputs[name], **profiles[name]} for name in inputs},
    }


def combine(paths: Sequence[Path]) -> dict[str, Any]:
    """The records of several runs (each of its own seeds, the same rows, restorer and held-out scenes) as one:
    the per-seed PSNRs side by side, summarised again (:func:`summarise`)."""
    records = [json.loads(path.read_text()) for path in paths]
    first = records[0]
    for path, record in zip(paths, records, strict=True):
        for key in ("held_out", "restorer", "capture_psnr_db"):
            if record[key] != first[key]:
                raise ValueError(f"{path}: {key} differs from {paths[0]}'s; only runs of one setting combine")
        if set(record["psnr_db"]) != set(first["psnr_db"]):
            raise ValueError(f"{path}: rows {sorted(record['psnr_db'])} differ from {sorted(first['psnr_db'])}")
    seeds = [seed for record in records for seed in record["seeds"]]
    if len(set(seeds)) != len(seeds):
        raise ValueError(f"a seed is in two runs: {seeds}")
    psnr = {name: [row for record in records for row in record["psnr_db"][name]] for name in first["psnr_db"]}
    unaligned = first["summary"]["capture_unaligned_psnr_db"]
    summary = summarise(psnr, first["capture_psnr_db"], [unaligned])
    print(format_table(summary, seeds))
    return {
        "psnr_db": psnr,
        "capture_psnr_db": first["capture_psnr_db"],
        "summary": summary,
        "seeds": seeds,
        "runs": [str(path) for path in paths],
        **{key: first[key] for key in ("held_out", "restorer", "camdegrade", "torch")},
        "wall_seconds": [record["wall_seconds"] for record in records],
        "cpu_seconds": [record["cpu_seconds"] for record in records],
    }


def write_crops(outcome: dict[str, Any], seed: int, path: Path) -> None:
    """Clean | capture | built-in simulation | restored by the real row | by the built-in row (seed ``seed``)."""
    trained, reference = outcome["trained"], outcome["reference"]
    panel = {
        scene: [("textured 2x", [*crops, *(trained[name, seed]["crops"][scene] for name in PANEL)])]
        for scene, crops in reference["crops"].items()
    }
    columns = ["clean", "real capture", "built-in simulation", *(f"restored: {name}" for name in PANEL)]
    write_panel(panel, columns, path)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--real-pairs", type=Path, default=None, help="the real-pairs folder")
    parser.add_argument("--rows", nargs="+", default=list(ROWS), choices=ROWS, help="rows to train")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--steps", type=int, default=Restorer.steps, help="restorer training steps")
    parser.add_argument("--compare", type=int, default=55, help="training scenes whose inputs are compared")
    parser.add_argument("--quick", action="store_true", help="one seed, 150 steps, the 3 shown held-out scenes")
    parser.add_argument("--unpaired", type=Path, default=DEFAULT_UNPAIRED, help="the unpaired profile's file")
    parser.add_argument("--built-in", default=BUILT_IN, help="the built_in row's profile: a built-in's name or a file")
    parser.add_argument("--workers", type=int, default=2, help="processes (one thread each)")
    parser.add_argument("--json", type=Path, default=Path("out/bench/restoration_transfer.json"))
    parser.add_argument("--png", type=Path, default=Path("out/bench/restoration_transfer.png"))
    parser.add_argument("--patch", type=int, default=Restorer.patch, help="side of the training windows")
    parser.add_argument("--combine", type=Path, nargs="+", help="merge these runs' JSON (one seed each) into --json")
    args = parser.parse_args(argv)
    if args.combine:
        write_json(args.json, combine(args.combine))
        return 0
    root = args.real_pairs or Path(os.environ.get("CAMDEGRADE_REAL_PAIRS") or DEFAULT_DATA)
    if not (root / "pairs.csv").is_file():
        print(f"restoration transfer skipped: no pairs.csv in {root} (set CAMDEGRADE_REAL_PAIRS)")
        return 0
    missing = missing_scenes(root)
    if missing:
        shown = ", ".join(missing[:5]) + (", ..." if len(missing) > 5 else "")
        print(
            f"restoration transfer skipped: {root / 'pairs.csv'} lacks {len(missing)} City100 iPhone X scenes ({shown})"
        )
        return 0
    held_out = SHOWN if args.quick else HELD_OUT
    if args.quick:
        args.steps, args.seeds, args.compare = QUICK["steps"], QUICK["seeds"], QUICK["compare"]
        if "unpaired" in args.rows and not args.unpaired.is_file():
            print(f"--quick: the unpaired row left out (no {args.unpaired}; a full run fits it there)")
            args.rows = [name for name in args.rows if name != "unpaired"]
    names = sorted(set(args.rows) | {"real", "colour_map"}, key=ROWS.index)
    config = replace(Restorer(), steps=args.steps, patch=args.patch)
    started, cpu_started = time.perf_counter(), time.process_time()
    rows, fitted = make_rows(root.resolve(), names, args.unpaired, args.built_in)
    outcome = run(root.resolve(), held_out, rows, config, args.seeds, args)
    wall = time.perf_counter() - started
    cpu = time.process_time() - cpu_started + outcome["reference"]["cpu"]
    cpu += sum(job["cpu"] for job in outcome["trained"].values())
    record = report(outcome, names, args.seeds, args.compare)
    if all(name in names for name in PANEL):
        write_crops(outcome, args.seeds[0], args.png)
        print(f"wrote {args.png}")
    print(
        f"\nrestorer {config}; seeds {args.seeds}; held-out {', '.join(held_out)}; fitted {fitted}\n"
        f"{wall / 60:.1f} min wall, {cpu / 60:.1f} min CPU, {args.workers} worker processes, {os.cpu_count()} cores, "
        f"{platform.machine()}, torch {torch.__version__}"
    )
    record.update(
        run_facts(args.workers, args.seeds, wall, cpu), restorer=asdict(config), held_out=list(held_out), fitted=fitted
    )
    write_json(args.json, record)
    return 0


if __name__ == "__main__":
    sys.exit(main())
