"""A fast slice of the diagnosis's own suite (``bench/bench_diagnose.py``, which runs every scenario on more pairs):
a stage to refit (noise twice too strong), the network to refit (a checkerboard), and the control, on 24 + 24 pairs
of 128². Each must accept the expected change first, close most of the gap, and leave the critic less able to tell
real from simulated; the control must accept nothing."""

from __future__ import annotations

from types import ModuleType

import pytest
import torch

from conftest import load_script

pytestmark = pytest.mark.slow
torch.set_num_threads(1)


@pytest.fixture(scope="module")
def bench() -> ModuleType:
    return load_script("bench/bench_diagnose.py", "camdegrade_bench_diagnose")


@pytest.mark.parametrize(
    ("name", "candidates"),
    [
        ("noise-2x", ["noise", "tone"]),
        ("network-checkerboard", ["tone"]),
    ],
)
def test_the_expected_change_is_accepted_first(bench: ModuleType, name: str, candidates: list[str]) -> None:
    row = bench.run_scenario(name, 24, 24, 128, candidates=candidates)
    assert row["top1"] == row["expected"], row
    assert row["misfit"] == [row["expected"]] and row["missing_accepted"] == [] and row["correct"], row
    assert row["fraction_closed"] >= 0.5, row
    assert row["critic_after"] < row["critic_before"] or row["critic_before"] <= 0.6, row


def test_the_control_accepts_nothing(bench: ModuleType) -> None:
    row = bench.run_scenario("control", 24, 24, 128, candidates=["noise", "tone", "blur"])
    assert row["accepted"] == [] and row["correct"], row
    assert row["critic_before"] <= 0.6, row
