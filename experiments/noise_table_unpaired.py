"""Captures-only noise on the REAL PolyU, CC15 and SIDD pairs: the unpaired fit against the paired one and the oracle.

Per subset (cameras pooled; the halves alternate within each camera and ISO, as ``experiments/noise_table.py``'s
subset table does): :func:`camdegrade.fitting.unpaired.fit_unpaired` sees only the *captures* of the fitting half
(no clean image, their mean frames unused) and fits a noise stage from their flat regions; the paired
:meth:`camdegrade.effects.Noise.fit` sees the pairs of the same half. On the checking half, where the clean (mean)
image is flat, each fitted noise is simulated on the clean images and its std per channel and intensity bin is
divided by the real noise's; ``oracle`` is the real noise of the fitting half over that of the checking half (what
reproducing the fitting images' noise exactly would score). Printed: per subset, the median and the worst
``|log2 ratio|`` over the measurable bins of each. Run from the repo root::

    OMP_NUM_THREADS=1 .venv/bin/python experiments/noise_table_unpaired.py [REAL_PAIRS_DIR] [--measurement] \\
        [--calibrated] [--splits N]

``--measurement`` prints instead what limits the captures-only column (first the three captures of each subset
whose own-flat reading is furthest above their clean-referenced noise, then the table): on the checking half
itself, the noise read from each capture's own flat pixels (binned by its own local mean,
:func:`~camdegrade.fitting.unpaired.steps.noise.flat_sums`, what the unpaired fit matches) against the real noise there
(clean-referenced), with no fit between:
how much of the error is the single-image measurement (content texture, the capture's own mask and bins).
``--splits N`` repeats the table over N halvings (the first as above, the others with each camera and ISO group
shuffled first) and prints each column's mean and how often the captures-only stage is at least as close as the
oracle. ``--calibrated`` adds a column: the captures' own-flat moments matched by simulated moments on the fitting
half's clean images (what turning the measurement into a stage by calibration gives at best).
"""

from __future__ import annotations

import argparse
import random
import statistics
import sys
from collections import defaultdict
from collections.abc import Sequence
from functools import partial
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from noise_table import SUBSETS, _load, _residual_sums, _simulate, default_real_pairs_dir, noise_groups

from camdegrade.effects import Noise
from camdegrade.fitting.unpaired import MIN_IMAGES, fit_unpaired
from camdegrade.fitting.unpaired.fit import STAND_IN_SIGMA
from camdegrade.fitting.unpaired.steps.noise import FINE_WINDOW, flat_sums, judge_noise, propose_noise
from camdegrade.functional.optics.blur import blur_image


def _spread(ratio: torch.Tensor) -> tuple[float, float, int]:
    """Median and worst ``|log2 ratio|`` over the finite bins, and how many there are."""
    values = ratio.flatten()
    values = values[torch.isfinite(values) & (values > 0)].log2().abs()
    return float(values.median()), float(values.max()), int(values.numel())


def _subsets(root: Path, split: int = 0) -> dict[str, list[tuple[Path, Path]]]:
    """Subset → its pairs, camera and ISO groups one after the other, so that the even-indexed pairs (the fitting
    half) and the odd-indexed ones (the checking half) alternate within each group. ``split`` 0 keeps the
    manifest's order in each group; another value shuffles each group with that seed first (another halving)."""
    ordered: dict[str, list[tuple[Path, Path]]] = defaultdict(list)
    for (subset, _, _), paths in noise_groups(root, SUBSETS).items():
        group = list(paths)
        if split:
            random.Random(split).shuffle(group)
        ordered[subset] += group
    return ordered


def worst_images(root: Path, count: int = 3) -> list[dict]:
    """Per subset, over both halves: the ``count`` captures whose own flat-pixel noise (pooled over channels and
    bins) is furthest above their clean-referenced noise: where the single-image reading takes texture for noise."""
    rows = []
    for subset, paths in _subsets(root).items():
        ratios = []
        for clean_path, real_path in paths:
            (clean,), (real,) = _load([(clean_path, real_path)])
            truth = _residual_sums([real], [clean]).pooled_std()
            ratios.append((flat_sums([real]).pooled_std() / truth, real_path.name))
        for ratio, name in sorted(ratios, reverse=True)[:count]:
            rows.append({"subset": subset, "capture": name, "own / clean-referenced": round(ratio, 2)})
    return rows


def measurement_rows(root: Path) -> list[dict]:
    """Per subset, on the checking half: the captures' own flat-pixel noise over the clean-referenced real noise."""
    rows = []
    for subset, paths in _subsets(root).items():
        held_cleans, held_reals = _load(paths[1::2])
        real, own = _residual_sums(held_reals, held_cleans), flat_sums(held_reals)
        row = {"subset": subset, "check": len(held_reals), "flat_pixels": real.pixels, "own_pixels": own.pixels}
        rows.append(row | {"own flat pixels": _spread(own.std() / real.std())})
    return rows


def subset_rows(root: Path, only: Sequence[str] | None = None, calibrated: bool = False, split: int = 0) -> list[dict]:
    """Per subset (``only`` these, default all): the captures-only and paired stages' and the oracle's spread;
    ``calibrated`` adds the captures' own-flat moments matched by simulation on the fitting half's *clean* images
    (the calibration the captures-only fit used until 2026-11-27, given the best source it could have); ``split``
    picks the halving (:func:`_subsets`)."""
    rows = []
    for subset, paths in _subsets(root, split).items():
        if only is not None and subset not in only:
            continue
        cleans, reals = _load(paths[::2])
        held_cleans, held_reals = _load(paths[1::2])
        real = _residual_sums(held_reals, held_cleans)
        stages = {
            "unpaired (captures only)": _captures_only_noise(reals),
            "paired Noise.fit": Noise.fit(cleans, reals, estimator="residual", seed=0),
        }
        if calibrated:
            simulate = partial(_simulate_or_clean, cleans=cleans)
            own = flat_sums(reals, FINE_WINDOW)  # read as the calibration reads the simulations
            stages["own moments calibrated on clean"] = judge_noise(propose_noise(own, simulate), own)
        row = {"subset": subset, "fit": len(reals), "check": len(held_reals), "flat_pixels": real.pixels}
        for label, noise in stages.items():
            sims = _simulate(noise, held_cleans, 1) if noise is not None else held_cleans
            row[label] = _spread(_residual_sums(sims, held_cleans).std() / real.std())
        row["oracle"] = _spread(_residual_sums(reals, cleans).std() / real.std())
        rows.append(row)
    return rows


def _captures_only_noise(reals: list[torch.Tensor]) -> Noise | None:
    """The noise stage ``fit_unpaired(reals, effects=("noise",))`` keeps; below its :data:`MIN_IMAGES` captures
    (SIDD's halves hold 6), the same step it runs, on the same stand-ins, called directly."""
    if len(reals) >= MIN_IMAGES:
        unpaired = fit_unpaired(reals, effects=("noise",)).effects
        return unpaired[0] if len(unpaired) else None
    stand_ins = [blur_image(image, STAND_IN_SIGMA) for image in reals]
    real = flat_sums(reals)
    return judge_noise(propose_noise(real, partial(_simulate_or_clean, cleans=stand_ins), direct=True), real)


def _simulate_or_clean(noise: Noise | None, cleans: list[torch.Tensor]) -> list[torch.Tensor]:
    return cleans if noise is None else _simulate(noise, cleans, 1)


def print_splits(root: Path, splits: int) -> None:
    """Per subset, over ``splits`` halvings: the mean median and worst |log2| of each column, and in how many the
    captures-only stage is at least as close as the oracle (one halving is one draw of which captures fit and which
    check), and the range of the oracle's median over them."""
    columns = ("unpaired (captures only)", "paired Noise.fit", "oracle")
    rows = [row for split in range(splits) for row in subset_rows(root, split=split)]
    heads = " | ".join(f"{c}: mean median / worst" for c in columns)
    print(f"| subset | halvings | {heads} | oracle median, lowest–highest | unpaired ≤ oracle |")
    print("|---|---|" + "---|" * (len(columns) + 2))
    for subset in dict.fromkeys(row["subset"] for row in rows):
        mine = [row for row in rows if row["subset"] == subset]
        cells = [
            f"{statistics.mean(r[c][0] for r in mine):.3f} / {statistics.mean(r[c][1] for r in mine):.3f}"
            for c in columns
        ]
        median_wins = sum(r[columns[0]][0] <= r["oracle"][0] for r in mine)
        worst_wins = sum(r[columns[0]][1] <= r["oracle"][1] for r in mine)
        wins = f"median {median_wins} of {len(mine)}, worst {worst_wins} of {len(mine)}"
        oracle = [r["oracle"][0] for r in mine]
        spread = f"{min(oracle):.2f}–{max(oracle):.2f}"
        print(f"| {subset} | {len(mine)} | " + " | ".join(cells) + f" | {spread} | {wins} |")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("root", nargs="?", type=Path, default=default_real_pairs_dir())
    parser.add_argument("--measurement", action="store_true", help="the single-image measurement's error only")
    parser.add_argument("--calibrated", action="store_true", help="add the calibration by simulated moments")
    parser.add_argument(
        "--splits", type=int, default=0, help="repeat over this many halvings (0 and N-1 shuffled ones) and summarise"
    )
    args = parser.parse_args(argv)
    if args.splits < 0 or (args.splits and (args.measurement or args.calibrated)):
        parser.error(f"--splits must be 0 or more and goes alone, got --splits {args.splits}")
    torch.set_num_threads(1)
    if args.splits:
        print_splits(args.root, args.splits)
        return 0
    if args.measurement:
        print("| subset | capture | own-flat noise / clean-referenced (pooled) |\n|---|---|---|")
        for row in worst_images(args.root):
            print(f"| {row['subset']} | {row['capture']} | {row['own / clean-referenced']:.2f} |")
        print()
        print("| subset | check images | flat pixels: clean-referenced / captures' own | own-flat noise / real |")
        print("|---|---|---|---|")
        for row in measurement_rows(args.root):
            median, worst, bins = row["own flat pixels"]
            print(
                f"| {row['subset']} | {row['check']} | {row['flat_pixels']} / {row['own_pixels']} | "
                f"{median:.2f} / {worst:.2f} ({bins} bins) |"
            )
        return 0
    columns = ("unpaired (captures only)", "paired Noise.fit", "oracle")
    if args.calibrated:
        columns = ("own moments calibrated on clean", *columns)
    print("| subset | fit / check images | flat pixels (check) | " + " | ".join(columns) + " |")
    print("|---|---|---|" + "---|" * len(columns))
    for row in subset_rows(args.root, calibrated=args.calibrated):
        cells = [f"{row[c][0]:.2f} / {row[c][1]:.2f} ({row[c][2]} bins)" for c in columns]
        print(f"| {row['subset']} | {row['fit']} / {row['check']} | {row['flat_pixels']} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
