"""Captures-only noise on REAL captures (``experiments/noise_table_unpaired.py``): CC15's fitting-half captures alone
(no clean image) give a noise stage that, simulated on the checking half's clean images, is at least as close to the
real noise there, per channel and intensity bin, as the fitting half's own real noise is (the oracle). Measured
2026-11-28: median / worst ``|log2|`` 0.19 / 0.70 against the oracle's 0.25 / 0.87 (0.27 / 0.80 before the
noise-aware flat mask; the calibrated stage before that: 0.45 / 1.18). And on SIDD's strong noise the captures' own
flat pixels read the noise the clean references show (0.05 / 0.68 on 17 bins; 0.22 / 1.84 on 8 bins with the
absolute mask). Skipped when
the shared real-pairs folder is absent."""

from __future__ import annotations

from pathlib import Path

import pytest

from conftest import load_script

pytestmark = [pytest.mark.realdata, pytest.mark.slow]


def test_captures_only_noise_is_about_as_close_as_the_oracle(real_pairs_dir: Path) -> None:
    example = load_script("experiments/noise_table_unpaired.py", "camdegrade_noise_table_unpaired_example")
    (row,) = example.subset_rows(real_pairs_dir, only=("cc15_nam_real_noise",))
    (median, worst, bins), (oracle_median, oracle_worst, _) = row["unpaired (captures only)"], row["oracle"]
    assert bins >= 18, row
    assert median <= oracle_median and worst <= oracle_worst, row


def test_strong_phone_noise_is_read_on_the_captures_own_flat_pixels(real_pairs_dir: Path) -> None:
    example = load_script("experiments/noise_table_unpaired.py", "camdegrade_noise_table_unpaired_example")
    rows = {row["subset"]: row for row in example.measurement_rows(real_pairs_dir)}
    median, worst, bins = rows["sidd_samples"]["own flat pixels"]
    assert bins >= 15 and median <= 0.1 and worst <= 0.8, rows["sidd_samples"]
