"""How long the command line takes to answer, against how long ``import torch`` alone takes (issue 19).

Plain script, not a test. ``camdegrade --help``, ``--version``, ``list`` and ``info`` import neither torch nor
torchvision, so they should answer well before torch could even be imported. Each round runs every command once as
a fresh process (wall time, start-up included), interleaved so that a slow spell of the machine slows all of them
alike; the table gives the median over the rounds. The target: ``camdegrade --help`` under 0.5 s. Run from the repo
root::

    .venv/bin/python bench/bench_cli.py          # writes out/bench/cli.json; exit status 1 if the target is missed
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

TARGET_S = 0.5


def cli() -> list[str]:
    """The installed ``camdegrade`` script beside this Python (what users type), else ``python -m camdegrade``."""
    script = Path(sys.executable).parent / "camdegrade"
    return [str(script)] if script.is_file() else [sys.executable, "-m", "camdegrade"]


def wall_time(command: list[str]) -> float:
    started = time.perf_counter()
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - started


def cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--out", type=Path, default=Path("out/bench/cli.json"))
    args = parser.parse_args()
    cases = {
        "camdegrade --help": [*cli(), "--help"],
        "camdegrade --version": [*cli(), "--version"],
        "camdegrade list": [*cli(), "list"],
        "camdegrade info city100-iphonex": [*cli(), "info", "city100-iphonex"],
        'python -c "import torch"': [sys.executable, "-c", "import torch"],
        'python -c "pass" (start-up alone)': [sys.executable, "-c", "pass"],
    }
    print(f"cpu: {cpu_name()}, python {platform.python_version()}, cli: {' '.join(cli())}")
    for command in cases.values():  # untimed: warm the file cache
        wall_time(command)
    times: dict[str, list[float]] = {name: [] for name in cases}
    for _ in range(args.rounds):
        for name, command in cases.items():
            times[name].append(wall_time(command))
    medians = {name: statistics.median(values) for name, values in times.items()}
    print(f"\n| command (median of {args.rounds} runs, wall time) | seconds |\n|---|---:|")
    for name, seconds in medians.items():
        print(f"| `{name}` | {seconds:.3f} |")
    help_s, torch_s = medians["camdegrade --help"], medians['python -c "import torch"']
    passed = help_s < TARGET_S
    print(f"\nimport torch / camdegrade --help: {torch_s / help_s:.1f}x")
    print(f"target camdegrade --help < {TARGET_S} s: {'PASS' if passed else 'FAIL'} ({help_s:.3f} s)")
    report = {
        "cpu": cpu_name(),
        "python": platform.python_version(),
        "rounds": args.rounds,
        "median_s": medians,
        "runs_s": times,
        "torch_import_over_help": torch_s / help_s,
        "target_s": TARGET_S,
        "passed": passed,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2) + "\n")
    return 0 if passed else 1


if __name__ == "__main__":
    sys.exit(main())
