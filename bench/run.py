"""``make bench``: run every ``bench/bench_*.py`` script in turn (each prints a table, writes JSON to out/bench/),
except the long research benches (:data:`LONG`: hours on 2 cores at their defaults), which ``--all`` adds."""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

#: Benches that train many networks or fit many profiles at their defaults: run them on their own (their docstrings
#: and docs/results.md give the commands and sizes the published numbers used).
LONG = {
    "bench_foreign_diagnosis.py": "a default fit and a diagnosis per withheld-effect scenario",
    "bench_foreign_fit.py": "a default fit of each of the 8 foreign cameras",
    "bench_restoration_transfer.py": "a restorer trained per row and seed",
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--all", action="store_true", help="also the long research benches: " + ", ".join(LONG))
    args = parser.parse_args(argv)
    scripts = sorted(Path(__file__).parent.glob("bench_*.py"))
    failed = []
    for script in scripts:
        if script.name in LONG and not args.all:
            print(f"== {script.name}: left out ({LONG[script.name]}; python bench/run.py --all)", flush=True)
            continue
        print(f"== {script.name}", flush=True)
        if subprocess.run([sys.executable, str(script)], check=False).returncode != 0:
            failed.append(script.name)
    if failed:
        print(f"failed: {', '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
