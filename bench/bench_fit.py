"""Time to a good profile: the fast recipe against the paper's, on City100 and a simulated camera (issue 18, part 3).

Plain script, not a test: it runs ``experiments/recipe_comparison.py`` (both recipes on each data set, same code,
machine and seed) and prints, per data set, whether the fast recipe reached the paper recipe's best validation PSNR
(within 0.1 dB) in at most a quarter of the paper recipe's wall time. City100 needs ``../shared/data/real-pairs``
beside the checkout (or ``CAMDEGRADE_REAL_PAIRS``); without it only the simulated camera runs. About 5 minutes on
2 cores with native bfloat16. Run from the repo root::

    .venv/bin/python bench/bench_fit.py          # writes out/bench/fit.json
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))

from fit_city100 import DEFAULT_DATA
from recipe_comparison import main as compare


def main() -> int:
    real_pairs = Path(os.environ.get("CAMDEGRADE_REAL_PAIRS") or DEFAULT_DATA)
    data = ["city100", "simulated"] if (real_pairs / "pairs.csv").is_file() else ["simulated"]
    if "city100" not in data:
        print(f"City100 skipped: no pairs.csv in {real_pairs}")
    return compare(["--data", *data, "--real-pairs", str(real_pairs), "--json", "out/bench/fit.json"])


if __name__ == "__main__":
    sys.exit(main())
