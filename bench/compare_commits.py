"""This checkout's ``CameraDegrade`` against another commit's, in one process: time per call (interleaved rounds, so a
busy machine's drift hits both alike) and how far apart their bytes are.

Not part of ``make bench`` (it needs the other tree). Export the other commit's sources and point at them::

    mkdir -p /tmp/other && git archive e826a1a src | tar -x -C /tmp/other
    .venv/bin/python bench/compare_commits.py --other /tmp/other [--threads 1] [--cpu-time]

The other tree's ``camdegrade`` is copied to a temporary folder as ``camdegrade_other`` (its imports renamed), so both
load side by side. ``--cpu-time`` times with the thread's CPU clock instead of the wall clock: on a machine shared with
other jobs it counts this process's work, not its waiting (use it with ``--threads 1``). Prints, per built-in profile:
ms per single-image call (median and min over the rounds) of each tree and their ratio; the network alone and the
effect stages alone; the bytes of both on four scikit-image photos at several sizes, odd sizes and batches (max
difference in levels, share within one level, share equal), at ``precision="float32"`` and ``"auto"``.
"""

from __future__ import annotations

import argparse
import importlib
import re
import shutil
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import torch
from bench_transform import natural_image

import camdegrade

PROFILES = ("city100-iphonex", "city100-iphonex-fast")
#: (height, width, images) of the byte comparison: whole photos, odd sizes, batches, tiny images.
SHAPES = ((224, 224, 1), (224, 224, 4), (37, 61, 2), (129, 255, 1), (300, 400, 3), (5, 9, 2), (1, 1, 1))


def load_other(source: Path, workdir: Path):
    """The other tree's package, copied into ``workdir`` as ``camdegrade_other``."""
    package = source / "src" / "camdegrade"
    if not (package / "__init__.py").is_file():
        raise SystemExit(f"--other must hold src/camdegrade/__init__.py, got {source}")
    target = workdir / "camdegrade_other"
    shutil.copytree(package, target)
    pattern = re.compile(r"\bcamdegrade(?=[.\s]|$)")
    for path in target.rglob("*.py"):
        path.write_text(pattern.sub("camdegrade_other", path.read_text()))
    sys.path.insert(0, str(workdir))
    return importlib.import_module("camdegrade_other")


def timed_rounds(cases: dict[str, Callable[[], object]], rounds: int, calls: int, clock) -> dict[str, list[float]]:
    """ms per call of every case in each round, the cases timed in turn within a round."""
    times: dict[str, list[float]] = {name: [] for name in cases}
    for _ in range(rounds):
        for name, step in cases.items():
            step(), step()
            started = clock()
            for _ in range(calls):
                step()
            times[name].append((clock() - started) / calls * 1000)
    return times


def timing_cases(trees: dict, name: str, image: torch.Tensor) -> dict[str, Callable[[], object]]:
    cases = {}
    for tag, package in trees.items():
        degrade = package.CameraDegrade(name, seed=0)
        inference = importlib.import_module(package.__name__ + ".inference")
        chain = importlib.import_module(package.__name__ + ".effects.chain")
        profile = degrade.profile
        with torch.no_grad():
            output = inference.run_network(profile.network, image[None], degrade.precision)
        params = profile.make_params(output.shape)
        cases[f"{tag} call"] = lambda degrade=degrade: degrade(image)
        cases[f"{tag} network"] = lambda inference=inference, profile=profile, degrade=degrade: inference.run_network(
            profile.network, image[None], degrade.precision
        )
        cases[f"{tag} effects"] = lambda chain=chain, profile=profile, output=output, params=params: (
            chain.apply_effects(profile.effects, params, output)
        )
    return cases


def byte_distance(trees: dict, name: str, precision: str) -> dict[str, float]:
    from skimage import data

    photos = [
        torch.from_numpy(getattr(data, n)()).permute(2, 0, 1) for n in ("astronaut", "chelsea", "coffee", "rocket")
    ]
    worst, within, equal, total = 0, 0, 0, 0
    for height, width, count in SHAPES:
        image = torch.stack([photo[:, :height, :width] for photo in photos[:count]]).contiguous()
        ours, theirs = (package.CameraDegrade(name, seed=5, precision=precision)(image) for package in trees.values())
        levels = (ours.int() - theirs.int()).abs()
        worst = max(worst, int(levels.max()))
        within, equal, total = (
            within + int((levels <= 1).sum()),
            equal + int((levels == 0).sum()),
            total + levels.numel(),
        )
    return {"max_levels": worst, "within_one": within / total, "equal": equal / total, "values": total}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--other", type=Path, required=True, help="a folder holding the other commit's src/")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--rounds", type=int, default=9)
    parser.add_argument("--calls", type=int, default=10)
    parser.add_argument("--cpu-time", action="store_true", help="time with the thread's CPU clock")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    clock = time.thread_time if args.cpu_time else time.perf_counter
    with tempfile.TemporaryDirectory() as workdir:
        trees = {"this": camdegrade, "other": load_other(args.other, Path(workdir))}
        image = natural_image()
        print(f"{args.threads} threads, {'thread CPU time' if args.cpu_time else 'wall time'}, {args.rounds} rounds")
        for name in PROFILES:
            times = timed_rounds(timing_cases(trees, name, image), args.rounds, args.calls, clock)
            for part in ("call", "network", "effects"):
                ours, theirs = times[f"this {part}"], times[f"other {part}"]
                ratios = [o / t for o, t in zip(ours, theirs, strict=True)]
                print(
                    f"{name:22s} {part:8s} this {statistics.median(ours):7.3f} (min {min(ours):.3f}) ms, other "
                    f"{statistics.median(theirs):7.3f} (min {min(theirs):.3f}) ms; this/other "
                    f"{statistics.median(ratios):.2f} (rounds {min(ratios):.2f}–{max(ratios):.2f})"
                )
            for precision in ("float32", "auto"):
                distance = byte_distance(trees, name, precision)
                print(
                    f"{name:22s} bytes, {precision:7s}: max {distance['max_levels']} level(s) apart, "
                    f"{distance['within_one']:.6f} within one level, {distance['equal']:.6f} equal "
                    f"({distance['values']} values)"
                )


if __name__ == "__main__":
    main()
