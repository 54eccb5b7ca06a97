"""The foreign cameras' comparison without and with the learned texture option (``bench/foreign_learned_compare.py``):
issue 43's rule for the paired default, read off two rows of ``bench_foreign_fit.py``."""

from __future__ import annotations

import json
from pathlib import Path

from conftest import load_script

compare = load_script("bench/foreign_learned_compare.py", "foreign_learned_compare")


def _row(critic: float, sampled: float, mean: float, **extra: object) -> dict:
    row = {"camera": "phone", "critic_held_out_image_only": critic, "psnr_sampled": sampled, "psnr_mean": mean}
    return {**row, "stages": ["network (local_affine)", "noise"], "fit_seconds": 100.0, "warnings": [], **extra}


def test_the_rule_needs_a_lower_critic_and_both_psnrs_within_three_tenths() -> None:
    without = _row(0.75, 26.66, 29.12)
    assert compare.verdict(without, _row(0.70, 26.40, 28.90)) == "yes"
    assert compare.verdict(without, _row(0.75, 26.66, 29.12)) == "no (critic)"
    assert compare.verdict(without, _row(0.70, 26.30, 29.12)) == "no (PSNR)"
    assert compare.verdict(without, _row(0.70, 26.66, 28.80)) == "no (PSNR)"
    assert compare.verdict(without, _row(0.80, 25.00, 29.12)) == "no (critic) (PSNR)"


def test_the_table_pairs_the_rows_of_two_runs_by_camera(tmp_path: Path) -> None:
    ungated = {"critic_held_out_image_only": 0.72, "psnr_sampled": 26.4, "psnr_mean": 28.95}
    gate = {"kept": False, "without": {"critic": 0.71, "psnr": 29.0}, "with": {"critic": 0.74, "psnr": 28.9}}
    for folder, row in (
        ("a", _row(0.75, 26.66, 29.12)),
        ("b", _row(0.70, 26.5, 29.0, learned_texture=gate, ungated=ungated)),
    ):
        (tmp_path / folder / "fit").mkdir(parents=True)
        (tmp_path / folder / "fit" / "phone.json").write_text(json.dumps(row))
    lines = compare.table(compare.rows_of(tmp_path / "a"), compare.rows_of(tmp_path / "b")).splitlines()
    assert len(lines) == 3
    assert lines[2].startswith(
        "| phone | 0.75 → 0.70 | 26.66 → 26.50 | 29.12 → 29.00 | dropped: 0.71 → 0.74, 29.00 → 28.90 "
        "| 0.72, 26.40 / 28.95 |"
    )
    assert lines[2].endswith("| yes |")
