"""The foreign cameras' default fits without and with the paired fit's learned texture option (issue 43): a table of
the rows ``bench_foreign_fit.py`` wrote to two ``--out`` folders (the second run with ``--learned-texture critic``),
and issue 43's rule for making the option the default: the held-out image-only critic falls and the held-out PSNR
(sampled and conditional mean) falls by at most 0.3 dB.

Run from the repo root::

    .venv/bin/python bench/foreign_learned_compare.py WITHOUT_OUT WITH_OUT

Columns: held-out image-only critic, PSNR sampled and mean (dB), without → with; the gate's record on the fit's own
validation pairs (fresh critic and the conditional mean's PSNR, without → with, kept or dropped); the same held-out
numbers of the fit with the stage its step trained, whether the gate kept it or not (the row's ``ungated``); the
stages the fit with the option kept; its fit seconds (wall, and CPU where recorded); whether each fit warned.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

#: Issue 43's rule: the held-out PSNR may fall by at most this much with the option.
MAX_PSNR_LOSS_DB = 0.3


def rows_of(folder: Path) -> dict[str, dict[str, Any]]:
    """The rows of ``folder/fit/*.json`` by camera."""
    return {row["camera"]: row for row in (json.loads(p.read_text()) for p in sorted((folder / "fit").glob("*.json")))}


def verdict(without: dict[str, Any], with_: dict[str, Any]) -> str:
    """Whether the row meets issue 43's rule: critic lower, both PSNRs within :data:`MAX_PSNR_LOSS_DB`."""
    critic = with_["critic_held_out_image_only"] < without["critic_held_out_image_only"]
    psnr = all(without[key] - with_[key] <= MAX_PSNR_LOSS_DB for key in ("psnr_sampled", "psnr_mean"))
    return "yes" if critic and psnr else "no" + ("" if critic else " (critic)") + ("" if psnr else " (PSNR)")


def gate_cell(record: dict[str, Any] | None) -> str:
    if not record:
        return "–"
    if "without" not in record:
        return record.get("reason", "not run")
    before, after = record["without"], record["with"]
    return (
        f"{'kept' if record['kept'] else 'dropped'}: {before['critic']:.2f} → {after['critic']:.2f}, "
        f"{before['psnr']:.2f} → {after['psnr']:.2f}"
    )


def ungated_cell(ungated: dict[str, float] | None) -> str:
    """The held-out numbers of the fit with its trained stage, whether the gate kept it or not."""
    if not ungated:
        return "–"
    return f"{ungated['critic_held_out_image_only']:.2f}, {ungated['psnr_sampled']:.2f} / {ungated['psnr_mean']:.2f}"


def table(without: dict[str, dict], with_: dict[str, dict]) -> str:
    lines = [
        "| camera | held-out critic image-only | PSNR sampled (dB) | PSNR mean (dB) | gate on validation: critic, "
        "PSNR mean | the stage ungated, held out: critic, PSNR sampled / mean | stages kept with the option "
        "| fit s wall / CPU (stage training wall) | warns without / with | rule met |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, row in with_.items():
        base = without.get(name)
        if base is None:
            continue
        cpu = row.get("fit_cpu_seconds")
        lines.append(
            f"| {name} | {base['critic_held_out_image_only']:.2f} → {row['critic_held_out_image_only']:.2f} "
            f"| {base['psnr_sampled']:.2f} → {row['psnr_sampled']:.2f} | {base['psnr_mean']:.2f} → "
            f"{row['psnr_mean']:.2f} | {gate_cell(row.get('learned_texture'))} | {ungated_cell(row.get('ungated'))} "
            f"| {', '.join(row['stages'])} "
            f"| {base['fit_seconds']:.0f} → {row['fit_seconds']:.0f} / {'–' if cpu is None else f'{cpu:.0f}'} "
            f"({(row.get('learned_texture') or {}).get('training_seconds', 0):.0f}) "
            f"| {'yes' if base['warnings'] else 'no'} / {'yes' if row['warnings'] else 'no'} | {verdict(base, row)} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("without", type=Path, help="--out of the run without the option")
    parser.add_argument("with_", metavar="with", type=Path, help="--out of the run with --learned-texture critic")
    args = parser.parse_args(argv)
    print(table(rows_of(args.without), rows_of(args.with_)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
