"""The scene assignments of ``experiments/unpaired_scene_assignment_city100.py`` (issue 43): each splits City100's
55 fitting scenes into 35 clean and 20 capture scenes, none on both sides, 0 being the issue's split; and on the real
frames (skipped without them) the content bias of the issue's split and the scenes' spread that docs/results.md
quotes: the capture scenes hold more fine detail than the clean ones, and a 35-vs-20 difference of set means carries
a standard error of about a quarter of a log2 per band whatever the fit does."""

from __future__ import annotations

from pathlib import Path

import pytest

from conftest import load_script

SCRIPT = load_script("experiments/unpaired_scene_assignment_city100.py", "camdegrade_unpaired_scene_assignment")


@pytest.mark.parametrize("k", [0, 1, 2, 8])
def test_an_assignment_splits_the_fitting_scenes_in_two(k: int) -> None:
    clean, captured = SCRIPT.assignment(k)
    assert len(clean) == 35 and len(captured) == 20
    assert not set(clean) & set(captured)
    assert set(clean) | set(captured) == set(SCRIPT.FITTING_SCENES)
    assert not set(clean + captured) & set(SCRIPT.HELD_OUT)
    assert SCRIPT.assignment(k) == (clean, captured)  # seeded


def test_assignment_zero_is_the_issue_s_split_and_the_others_differ() -> None:
    assert SCRIPT.assignment(0) == (SCRIPT.CLEAN_SCENES, SCRIPT.CAPTURED_SCENES)
    assert len({tuple(SCRIPT.assignment(k)[1]) for k in range(5)}) == 5


@pytest.mark.realdata
@pytest.mark.slow
def test_the_issue_s_capture_scenes_hold_more_fine_detail_and_the_scenes_spread_is_a_quarter_log2(
    real_pairs_dir: Path,
) -> None:
    scenes = SCRIPT.city100(real_pairs_dir)
    bias = SCRIPT.content_bias(scenes, *SCRIPT.assignment(0))
    assert bias[-3:] == pytest.approx([0.16, 0.28, 0.22], abs=0.01)
    precision = SCRIPT.assignment_precision(scenes)
    assert all(0.22 <= value <= 0.27 for value in precision["band_standard_error"])
    assert precision["statistic_standard_error"][-1] == pytest.approx(0.226, abs=0.002)
