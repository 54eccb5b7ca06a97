"""The PSNR-gap test: does a denoiser trained on simulated noise do as well on real captures as one trained on real
noise? (issue 25; the field's test of a noise model: DANet, ECCV 2020; PNGAN, NeurIPS 2021).

Plain script, not a test. For each real-noise subset (PolyU split by scene, CC15 and SIDD split by image) the same
small denoiser (``noise_gap_denoiser.py``) is trained once per row and seed on windows of the training split, with
the same initialisation and the same windows; only the noisy input differs by row (``noise_gap_rows.py``: real,
the fitted profile sampled as a whole, the noise stage alone, σ-matched Gaussian, fitted Poisson–Gaussian). Each
denoiser is scored by its PSNR on the full held-out real noisy images against their clean (mean) images; the gap
closure is ``(row − gaussian) / (real − gaussian)``. Beside it the AKLD (:func:`camdegrade.measures.akld.akld`) of
each row's noise on the held-out clean images against the real noise there (PNGAN: 0.153 on SIDD sRGB), and why a
row falls short (``noise_gap_evidence.py``: the noise's level by intensity, correlation, colour and shape).

The fits, trainings and measurements run in ``--workers`` processes of one thread each. Needs
``../shared/data/real-pairs`` beside the checkout (or ``CAMDEGRADE_REAL_PAIRS``); skipped without it. Run from the
repo root::

    .venv/bin/python bench/bench_noise_gap.py            # writes out/bench/noise_gap.json

References:
    Z. Yue et al., "Dual Adversarial Network: Toward Real-world Noise Removal and Noise Generation", ECCV 2020.
    Y. Cai et al., "Learning to Generate Realistic Noisy Images via Pixel-level Noise-aware Adversarial Training",
    NeurIPS 2021.
"""

from __future__ import annotations

import argparse
import math
import multiprocessing
import os
import platform
import statistics
import sys
import time
from collections.abc import Sequence
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import torch
from machine import run_facts, write_json
from noise_gap_denoiser import Denoiser, psnr_db, test_psnr, train_denoiser
from noise_gap_evidence import crops, format_evidence, noise_structure, write_panel
from noise_gap_rows import CROPS_PER_EPOCH, OPTIONAL_ROWS, PROFILE_RECIPE, ROWS, SUBSETS, Row, fit_rows, load_split

from camdegrade.measures.akld import akld

REPOSITORY = Path(__file__).resolve().parents[1]
DEFAULT_DATA = REPOSITORY.parent / "shared" / "data" / "real-pairs"
#: PNGAN's AKLD on SIDD sRGB (Cai et al. 2021, table 1).
PNGAN_AKLD = 0.153


# -- the jobs (run in the worker processes) --------------------------------------------------------------------------


def _one_thread() -> None:
    torch.set_num_threads(1)


def fit_job(root: Path, subset: str, names: Sequence[str]) -> tuple[dict[str, Row], dict[str, Any], float]:
    started = time.process_time()
    rows, fitted = fit_rows(load_split(root, subset), oracle="oracle" in names)
    return rows, fitted, time.process_time() - started


def train_job(root: Path, subset: str, row: Row, seed: int, config: Denoiser) -> tuple[float, float]:
    """The held-out PSNR of a denoiser trained on ``row``'s noisy training images, and the CPU seconds."""
    started = time.process_time()
    split = load_split(root, subset)
    cleans, captures = split.unit("train")
    model = train_denoiser(cleans, row.noisy(cleans, captures, seed, "gap-train"), config, seed)
    clean_test, capture_test = split.unit("test")
    return test_psnr(
        model, list(zip(clean_test, capture_test, strict=True)), config.fold
    ), time.process_time() - started


def measure_job(root: Path, subset: str, rows: dict[str, Row]) -> tuple[dict[str, Any], list, float]:
    """AKLD and the noise's structure of every row on the held-out clean images, against the real captures."""
    started = time.process_time()
    cleans, captures = load_split(root, subset).unit("test")
    structures, divergence, floor, first = {}, {}, {}, {}
    for name, row in rows.items():
        noisy = row.noisy(cleans, captures, 0, "gap-measure")
        structures[name] = noise_structure(noisy, cleans)
        first[name] = noisy[0]
        if name != "real":
            divergence[name] = round(akld(noisy, captures, cleans), 4)
            floor[name] = round(akld(row.noisy(cleans, captures, 1, "gap-measure"), noisy, cleans), 4)
    noisy_psnr = statistics.fmean(psnr_db(x, c) for c, x in zip(cleans, captures, strict=True))
    measured = {"akld": divergence, "akld_floor": floor, "noise": structures, "noisy_psnr_db": round(noisy_psnr, 3)}
    return measured, crops(first, cleans[0]), time.process_time() - started


# -- the run ---------------------------------------------------------------------------------------------------------


def run(
    root: Path, subsets: Sequence[str], names: Sequence[str], config: Denoiser, seeds: Sequence[int], workers: int
) -> dict[str, Any]:
    """Fit every subset's rows, then train and measure the rows ``names``, ``workers`` processes at a time; the
    results per subset and the CPU seconds of every job."""
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(workers, mp_context=context, initializer=_one_thread) as pool:
        fits = {pool.submit(fit_job, root, subset, names): subset for subset in subsets}
        rows, trainings, measures = {}, {}, {}
        for job in as_completed(fits):  # a subset's trainings start as soon as its rows are fitted
            subset = fits[job]
            rows[subset] = _logged(job, f"{subset}: rows fitted")
            chosen = {name: rows[subset][0][name] for name in names}
            measures[subset] = pool.submit(measure_job, root, subset, chosen)
            for seed in seeds:
                for name in names:
                    trainings[subset, name, seed] = pool.submit(
                        train_job, root, subset, rows[subset][0][name], seed, config
                    )
        scores = {key: _logged(job, f"{key[0]} seed {key[2]} {key[1]}") for key, job in trainings.items()}
        measured = {subset: measures[subset].result() for subset in subsets}
    results = []
    for subset in subsets:
        split = load_split(root, subset)
        result = {
            "subset": subset,
            "train_pairs": len(split.train),
            "test_pairs": len(split.test),
            "test_images": split.test_names,
            "test_megapixels": round(sum(c.shape[-1] * c.shape[-2] for c, _ in split.test) / 1e6, 2),
            "psnr_db": {name: [round(scores[subset, name, seed][0], 3) for seed in seeds] for name in names},
            "fitted": rows[subset][1],
            **measured[subset][0],
        }
        result["summary"] = summarise(result["psnr_db"])
        results.append(result)
    cpu = [job[-1] for job in (*rows.values(), *scores.values(), *measured.values())]
    panels = {subset: measured[subset][1] for subset in subsets}
    return {"results": results, "job_cpu_seconds": round(sum(cpu), 1), "panels": panels}


def _logged(job: Future, label: str) -> Any:
    result = job.result()
    detail = f"{result[0]:.3f} dB" if isinstance(result[0], float) else ""
    print(f"  {label} {detail} ({result[-1]:.0f} s CPU)", file=sys.stderr, flush=True)
    return result


def summarise(psnr: dict[str, list[float]]) -> dict[str, Any]:
    """Mean and spread (max − min over seeds) per row, gap to real, and each simulated row's gap closure
    ``(row − gaussian) / (real − gaussian)``."""
    mean = {name: statistics.fmean(values) for name, values in psnr.items()}
    spread = {name: max(values) - min(values) for name, values in psnr.items()}
    span = mean["real"] - mean["gaussian"]
    closure = {
        name: (mean[name] - mean["gaussian"]) / span if span > 0 else math.nan for name in psnr if name != "real"
    }
    return {
        "mean": mean,
        "spread": spread,
        "gap_to_real": {n: mean["real"] - mean[n] for n in psnr},
        "closure": closure,
    }


def format_table(results: Sequence[dict]) -> str:
    header = (
        f"{'subset':<20} {'row':<17} {'PSNR dB':>7} {'spread':>6} {'gap to real':>11} {'closure':>7} {'AKLD':>6} "
        f"{'floor':>6}"
    )
    lines = [header, "-" * len(header)]
    for result in results:
        summary = result["summary"]
        for name in result["psnr_db"]:
            closure = summary["closure"].get(name)
            divergence, floor = result["akld"].get(name), result["akld_floor"].get(name)
            lines.append(
                f"{result['subset']:<20} {name:<17} {summary['mean'][name]:>7.2f} {summary['spread'][name]:>6.2f} "
                f"{summary['gap_to_real'][name]:>11.2f} {'' if closure is None else f'{closure:.2f}':>7} "
                f"{'' if divergence is None else f'{divergence:.3f}':>6} {'' if floor is None else f'{floor:.3f}':>6}"
            )
        lines.append(
            f"{result['subset']:<20} {'(noisy input)':<17} {result['noisy_psnr_db']:>7.2f}  "
            f"{result['test_pairs']} held-out images ({result['test_megapixels']} Mpx), {result['train_pairs']} "
            "training pairs"
        )
    lines.append(
        f"spread: max − min over the seeds; AKLD of PNGAN on SIDD sRGB: {PNGAN_AKLD}; floor: the AKLD of a second "
        "draw of the row against the first (what the same noise scores)"
    )
    return "\n".join(lines)


def _recipe_text() -> str:
    values = {k: v for k, v in PROFILE_RECIPE.training_dict().items() if k != "crops_per_pair"}
    return f"{values}, crops per pair {CROPS_PER_EPOCH} / pairs (at least 8), effects {list(PROFILE_RECIPE.effects)}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--real-pairs", type=Path, default=None, help="the real-pairs folder")
    parser.add_argument("--subsets", nargs="+", default=list(SUBSETS), choices=SUBSETS)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument(
        "--rows",
        nargs="+",
        default=list(ROWS),
        choices=ROWS + OPTIONAL_ROWS,
        help="rows to train (real and gaussian always)",
    )
    parser.add_argument("--steps", type=int, default=Denoiser.steps, help="denoiser training steps")
    parser.add_argument("--workers", type=int, default=2, help="processes (one thread each)")
    parser.add_argument("--json", type=Path, default=Path("out/bench/noise_gap.json"))
    parser.add_argument("--png", type=Path, default=Path("out/bench/noise_gap.png"), help="real beside simulated")
    args = parser.parse_args(argv)
    root = args.real_pairs or Path(os.environ.get("CAMDEGRADE_REAL_PAIRS") or DEFAULT_DATA)
    if not (root / "pairs.csv").is_file():
        print(f"noise gap skipped: no pairs.csv in {root} (set CAMDEGRADE_REAL_PAIRS)")
        return 0
    names = ["real", "gaussian", *(name for name in args.rows if name not in ("real", "gaussian"))]
    names = sorted(names, key=(ROWS + OPTIONAL_ROWS).index)
    config = replace(Denoiser(), steps=args.steps)
    started, cpu_started = time.perf_counter(), time.process_time()
    report = run(root.resolve(), args.subsets, names, config, args.seeds, args.workers)
    wall = time.perf_counter() - started
    cpu = report["job_cpu_seconds"] + time.process_time() - cpu_started
    print(format_table(report["results"]))
    print()
    for result in report["results"]:
        print(format_evidence(result["subset"], result["noise"]))
    print(
        f"\ndenoiser {config}; seeds {args.seeds}; profile recipe: fast with {_recipe_text()}\n"
        f"{wall / 60:.1f} min wall, {cpu / 60:.1f} min CPU, "
        f"{args.workers} worker processes, {os.cpu_count()} cores, {platform.machine()}, torch {torch.__version__}"
    )
    write_panel(report.pop("panels"), ["clean", *names], args.png)
    print(f"wrote {args.png}")
    report.update(run_facts(args.workers, args.seeds, wall, cpu), denoiser=asdict(config))
    write_json(args.json, report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
