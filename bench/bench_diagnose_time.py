"""How long ``camdegrade diagnose`` takes on a foreign camera (issue 42: "100 pairs of 256² ≤ 120 s").

The case: the ``webcam`` camera of ``tests/foreign_cameras`` (a sensor of half the pixels zoomed back by the ISP,
written without camdegrade), fitted with the ``camdegrade fit`` defaults on ``--fit-pairs`` pairs of 128²
(``foreign_bench.fitted_profile``, kept on disk under ``--out``), and its ``defocus`` scenario's pairs written as a
pairs folder (``clean/``, ``captured/``). The command timed is the CLI a user runs::

    camdegrade diagnose PROFILE PAIRS --threads 2 --json REPORT

Run from the repo root::

    .venv/bin/python bench/bench_diagnose_time.py             # 100 pairs of 256²: PASS when ≤ 120 s
    .venv/bin/python bench/bench_diagnose_time.py --small    # 24 pairs of 128² (minutes; for iteration)
    .venv/bin/python bench/bench_diagnose_time.py --build-only   # write the profile and the pairs, time nothing
    .venv/bin/python bench/bench_diagnose_time.py --schedstat    # also: the time spent waiting for a CPU (Linux)

``--schedstat`` runs the same diagnosis through ``bench/diagnose_schedstat.py``, which reads each thread's scheduler
statistics: the seconds on a CPU, waiting for one (held by other processes), blocked (the GIL, a lock), and an
estimate of the wall time on an idle machine. On a shared machine the verdict is on the wall time measured, and the
estimate says whether the load or the work stands between it and the target.

Prints the seconds, the CPU and its load (``bench/machine.py``), and PASS/FAIL against the target; the report is kept
as ``OUT/CASE/report.json`` (compare two runs' reports with ``--compare A B``: everything but timings).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import torch
from foreign_bench import DIAGNOSIS_SEED, OTHER_PHOTOS, fitted_profile, make_pairs
from machine import cpu_description, load_text

from camdegrade.io import write_image
from foreign_cameras import SCENARIOS

#: Issue 42's target: seconds for the diagnosis of 100 pairs of 256².
TARGET_SECONDS = 120.0
BASE, SCENARIO = "webcam", "defocus"
#: The report's keys that hold timings (left out when two reports are compared).
TIMING_KEYS = {"seconds"}


def build(out: Path, pairs: int, size: int, fit_pairs: int) -> tuple[Path, Path]:
    """The fitted profile and the scenario's pairs folder under ``out`` (written once, reused after)."""
    profile, _ = fitted_profile(BASE, fit_pairs, 128, out)
    case = out / f"{BASE}-{SCENARIO}-{pairs}x{size}"
    profile_path = case / "profile.safetensors"
    folder = case / "pairs"
    if not (folder / "captured" / f"{pairs - 1:03d}.png").is_file():
        made = make_pairs(SCENARIOS[BASE][SCENARIO].camera(), pairs, size, DIAGNOSIS_SEED, OTHER_PHOTOS)
        for index, (clean, captured) in enumerate(made):
            write_image(clean, folder / "clean" / f"{index:03d}.png")
            write_image(captured, folder / "captured" / f"{index:03d}.png")
    if not profile_path.is_file():
        profile.save(profile_path)
    return profile_path, folder


def time_diagnose(profile: Path, pairs: Path, report: Path, threads: int, schedstat: bool = False) -> dict[str, Any]:
    """Wall time of the CLI's diagnosis (one process, as a user runs it); with ``schedstat``, through
    ``diagnose_schedstat.py``, whose summary is added as ``"schedstat"``."""
    if schedstat:
        command = [sys.executable, str(Path(__file__).with_name("diagnose_schedstat.py")), str(profile), str(pairs)]
        command += [str(report), "--threads", str(threads)]
    else:
        command = [sys.executable, "-m", "camdegrade", "diagnose", str(profile), str(pairs)]
        command += ["--threads", str(threads), "--json", str(report), "--quiet"]
    load = load_text()
    started = time.perf_counter()
    result = subprocess.run(command, capture_output=True, text=True, check=False)
    seconds = time.perf_counter() - started
    out = {
        "command": " ".join(command),
        "seconds": round(seconds, 1),
        "returncode": result.returncode,
        "load_before": load,
        "load_after": load_text(),
        "stderr": result.stderr[-400:],
    }
    if schedstat and result.returncode == 0:
        out["schedstat"] = json.loads(result.stdout.strip().splitlines()[-1])
    return out


def _without_timings(value: Any) -> Any:
    if isinstance(value, dict):
        return {key: _without_timings(item) for key, item in value.items() if key not in TIMING_KEYS}
    if isinstance(value, list):
        return [_without_timings(item) for item in value]
    return value


def compare(first: Path, second: Path) -> list[str]:
    """The top-level keys of two JSON reports that differ, timings left out."""
    a, b = (_without_timings(json.loads(path.read_text())) for path in (first, second))
    return sorted(key for key in set(a) | set(b) if a.get(key) != b.get(key))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--small", action="store_true", help="24 pairs of 128² instead of 100 of 256²")
    parser.add_argument("--fit-pairs", type=int, default=64, help="training pairs (128²) of the base's default fit")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--build-only", action="store_true")
    parser.add_argument("--schedstat", action="store_true", help="also the seconds waiting for a CPU (Linux)")
    parser.add_argument("--compare", nargs=2, type=Path, default=None, help="two report.json files")
    parser.add_argument("--out", type=Path, default=Path("/tmp/diagnose-time"))
    args = parser.parse_args(argv)
    if args.compare:
        differ = compare(*args.compare)
        print("same but timings" if not differ else f"differ: {', '.join(differ)}")
        return 1 if differ else 0
    torch.set_num_threads(1)
    pairs, size = (24, 128) if args.small else (100, 256)
    profile, folder = build(args.out, pairs, size, args.fit_pairs)
    if args.build_only:
        print(f"profile {profile}\npairs {folder}")
        return 0
    report = folder.parent / "report.json"
    result = time_diagnose(profile, folder, report, args.threads, args.schedstat)
    verdict = "PASS" if result["returncode"] == 0 and result["seconds"] <= TARGET_SECONDS else "FAIL"
    target = f"≤ {TARGET_SECONDS:.0f} s" if not args.small else "(small case: no target)"
    print(json.dumps(result, indent=2))
    print(
        f"diagnose {pairs}×{size}² {target}: {result['seconds']:.1f} s "
        f"{verdict if not args.small else ''} on {cpu_description()}; {result['load_before']}"
    )
    if "schedstat" in result:
        times = result["schedstat"]
        print(
            f"its threads waited {times['waiting_for_cpu']:.1f} s in all for a CPU other processes held; "
            f"{times['cpu']:.1f} CPU s, {times['tasks_blocked']:.1f} s blocked in side-by-side tasks; "
            f"estimated wall on an idle machine {times['idle_machine_estimate']:.1f} s"
        )
    return 0 if result["returncode"] == 0 and (args.small or verdict == "PASS") else 1


if __name__ == "__main__":
    sys.exit(main())
