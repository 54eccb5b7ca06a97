"""The diagnosis on cameras it did not build (issue 42): withheld-effect scenarios on foreign cameras.

Each base camera of ``tests/foreign_cameras`` (``webcam``: a sensor of half the pixels zoomed back by the ISP;
``phone``: a Bayer sensor with Hamilton-Adams demosaicing; both written with numpy, scipy and PIL only) is fitted with
the ``camdegrade fit`` defaults on its own pairs (``foreign_bench.fitted_profile``, shared with
``bench_foreign_fit.py``). That profile is then diagnosed with the ``camdegrade diagnose`` defaults (``diagnose()``:
every candidate, every kind of change, the critic, its split of the pairs by scene) on pairs of the base plus ONE
added effect (strong white noise after the resize, defocus, motion blur, misalignment, exposure, a colour cast,
vignetting, JPEG, 5-bit quantization, sharpening), and on pairs of the base itself (the control).

Scored as the diagnosis' own suite scores itself (``bench/bench_diagnose.py``, docs/diagnosis.md, *Validation*): a
scenario is right when the first accepted change names the added effect (``Scenario.expected``); a control is right
when nothing is accepted. A fitted base has a misfit of its own (what its control accepts), so the table also gives
the own suite's rule for a profile with a misfit (``underfit-*``): the first accepted change *beyond* the control's
must name the added effect. "Ranked first" is the statistics' best change (``report.changes[0]``), accepted or not
(held back by the critic check, say).

Run from the repo root (each scenario's row is written to ``OUT/diagnosis/BASE-SCENARIO.json`` as it finishes, so
runs can be split over processes and the table printed from the rows)::

    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_foreign_diagnosis.py                 # 40 pairs of 128² each
    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_foreign_diagnosis.py --quick         # 3 scenarios, 24 pairs
    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_foreign_diagnosis.py --table-only    # the table of the rows
    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_foreign_diagnosis.py --bases noisy-upscale --fit-pairs 64 --pairs 24

``--bases noisy-upscale`` (``foreign_cameras.CHECK_BASES``): a third base the diagnosis' rules were not designed on,
to check them on (a sensor of two thirds of the pixels, noise before and after its bicubic upscale, a tone table).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import torch
from foreign_bench import DEFAULT_OUT, DIAGNOSIS_SEED, OTHER_PHOTOS, fitted_profile, make_pairs, stages_of

from camdegrade.diagnose import diagnose
from foreign_cameras import BASES, CHECK_BASES, SCENARIOS, Scenario

CRITICS = ("before", "after", "before (image only)", "after (image only)")


def _label(change: dict[str, Any]) -> str:
    return f"{change['kind']} {change['name']}"


def _statistics_accepted(report: Any) -> list[str]:
    """What the statistics accepted before the image-only critic's check held any of it back."""
    check = report.critic_check or {}
    held = check.get("held_back") or {}
    return [*report.accepted, *([held["change"]] if held else []), *check.get("later_held_back", [])]


def _critic(report: Any, key: str) -> float | None:
    return (report.critic.get(key) or {}).get("accuracy")


def score(scenario: Scenario, report: Any, seconds: float) -> dict[str, Any]:
    """One row: what the diagnosis accepted and ranked, and whether it named the added effect."""
    expected = list(scenario.expected)
    ranked = [
        {"change": _label(c), "reduction": round(c["reduction"], 2), "significant": bool(c.get("significant"))}
        for c in report.changes[:5]
        if "reduction" in c
    ]
    first = report.accepted[0] if report.accepted else None
    held = (report.critic_check or {}).get("held_back") or {}
    where = sorted(report.where, key=lambda row: -(row.get("score") or 0.0))[:3]
    return {
        "base": scenario.base,
        "scenario": scenario.name,
        "expected": expected,
        "accepted": report.accepted,
        "statistics_accepted": _statistics_accepted(report),
        "first_accepted": first,
        "first_ranked": ranked[0]["change"] if ranked else None,
        "ranked": ranked,
        "expected_rank": next((i for i, c in enumerate(report.changes) if _label(c) in expected), None),
        "all_changes": [[_label(c), round(c["reduction"], 2)] for c in report.changes if "reduction" in c],
        "held_back": held.get("change"),
        "misfit": [_label(row) for row in report.misfit],
        "missing_first": _label(report.missing[0]) if report.missing else None,
        "right": (not report.accepted) if not expected else first in expected,
        "ranked_right": bool(ranked) and ranked[0]["change"] in expected,
        "gap_before": round(report.gap_before, 2),
        "gap_after": round(report.gap_after, 2),
        "noise_floor": round(report.noise_floor, 2),
        "fraction_closed": round(report.fraction_closed, 3),
        "where": [{"axis": row["axis"], "score": round(row["score"], 2), "finding": row["finding"]} for row in where],
        "critic": {
            key: _critic(report, key) for key in ("before", "after", "before (image only)", "after (image only)")
        },
        "verdict": report.verdict,
        "seconds": round(seconds, 1),
    }


def run(base: str, name: str, args: argparse.Namespace) -> dict[str, Any]:
    profile, fit_record = fitted_profile(base, args.fit_pairs, args.size, args.out)
    scenario = SCENARIOS[base][name]
    pairs = make_pairs(scenario.camera(), args.pairs, args.size, DIAGNOSIS_SEED, OTHER_PHOTOS)
    started = time.perf_counter()
    report = diagnose(profile, pairs, seed=args.seed, log=print if args.verbose else None)
    row = score(scenario, report, time.perf_counter() - started)
    row.update(pairs=args.pairs, size=args.size, profile_stages=stages_of(profile), fit=fit_record)
    return row


def _ranked_first(row: dict[str, Any]) -> str:
    """The statistics' best change with its held-out gap reduction (``*``: significant)."""
    if not row["ranked"]:
        return "–"
    ranked = row["ranked"][0]
    return f"{ranked['change']} ({ranked['reduction']:+.2f}{'*' if ranked['significant'] else ''})"


def beyond_control(row: dict[str, Any], rows: list[dict[str, Any]]) -> str | None:
    """The first accepted change that the base's control did not accept too: the own suite's rule for a profile
    with a misfit of its own (``underfit-*``: the misfit is reported as such, the added effect must be the first
    finding beside it). The base's misfit is what its control accepts."""
    control = next((other for other in rows if other["base"] == row["base"] and not other["expected"]), None)
    own = set(control["accepted"]) if control is not None else set()
    return next((change for change in row["accepted"] if change not in own), None)


def table(rows: list[dict[str, Any]]) -> str:
    lines = [
        "| base | scenario | expected | accepted | ranked first by the statistics (reduction) | held back "
        "| right: first accepted / first beyond the control's | gap before → after (floor) | s |",
        "|---|---|---|---|---|---|---|---|---:|",
    ]
    for row in rows:
        beyond = beyond_control(row, rows)
        row["right_beyond_control"] = beyond in row["expected"] if row["expected"] else None
        expected = " / ".join(row["expected"]) or "nothing"
        marks = {True: "yes", False: "**no**", None: "–"}
        right = f"{marks[row['right']]} / {marks[row['right_beyond_control']]}"
        lines.append(
            f"| {row['base']} | {row['scenario']} | {expected} | {', '.join(row['accepted']) or 'none'} "
            f"| {_ranked_first(row)} | {row['held_back'] or '–'} | {right} "
            f"| {row['gap_before']:.2f} → {row['gap_after']:.2f} ({row['noise_floor']:.2f}) | {row['seconds']:.0f} |"
        )
    lines.append("")
    for base in dict.fromkeys(row["base"] for row in rows):
        own = [row for row in rows if row["base"] == base and row["expected"]]
        controls = [row for row in rows if row["base"] == base and not row["expected"]]
        lines.append(
            f"{base}: the added effect accepted first in {sum(row['right'] for row in own)} of {len(own)}, first "
            f"beyond the control's changes in {sum(row['right_beyond_control'] for row in own)}, ranked first by the "
            f"statistics in {sum(row['ranked_right'] for row in own)}; control accepts "
            f"{', '.join(controls[0]['accepted']) or 'nothing' if controls else '(not run)'}"
        )
    return "\n".join(lines)


def write_fit_row(base: str, args: argparse.Namespace) -> None:
    """The base's row of ``bench_foreign_fit.py`` (same fit, same pairs), in this process: a profile that cannot be
    saved is fitted once for both benches."""
    import bench_foreign_fit

    row = bench_foreign_fit.measure(base, args)
    (args.out / "fit").mkdir(parents=True, exist_ok=True)
    (args.out / "fit" / f"{base}.json").write_text(json.dumps(row, indent=2) + "\n")


def _rows(folder: Path) -> list[dict[str, Any]]:
    bases = (*BASES, *CHECK_BASES)
    order = {(base, name): (i, j) for i, base in enumerate(bases) for j, name in enumerate(SCENARIOS[base])}
    rows = [json.loads(path.read_text()) for path in folder.glob("*.json")]
    return sorted(rows, key=lambda row: order.get((row["base"], row["scenario"]), (99, 99)))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "--bases", nargs="*", default=list(BASES), choices=(*BASES, *CHECK_BASES), help="CHECK_BASES: not designed on"
    )
    parser.add_argument("--scenarios", nargs="*", default=None, help="names of SCENARIOS[base] (default: all)")
    parser.add_argument("--pairs", type=int, default=40, help="pairs per scenario (the diagnosis splits them)")
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--fit-pairs", type=int, default=120, help="training pairs of the base's default fit")
    parser.add_argument("--quick", action="store_true", help="control, noise-after and defocus on 24 pairs")
    parser.add_argument("--table-only", action="store_true", help="print the table of the rows already written")
    parser.add_argument("--fit-rows", action="store_true", help="also write each base's row of the fit bench")
    parser.add_argument("--held-out", type=int, default=48, help="held-out pairs of the fit rows")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--verbose", action="store_true")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    folder = args.out / "diagnosis"
    if not args.table_only:
        folder.mkdir(parents=True, exist_ok=True)
        names = ["control", "noise-after", "defocus"] if args.quick else args.scenarios
        args.pairs = 24 if args.quick else args.pairs
        for base in args.bases:
            if args.fit_rows:
                write_fit_row(base, args)
            for name in names or list(SCENARIOS[base]):
                row = run(base, name, args)
                (folder / f"{base}-{name}.json").write_text(json.dumps(row, indent=2) + "\n")
                print(json.dumps({k: row[k] for k in ("base", "scenario", "accepted", "first_ranked", "right")}))
    print(table(_rows(folder)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
