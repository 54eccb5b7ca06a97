"""A fast slice of the diagnosis's own suite (``bench/bench_diagnose.py``, which runs every scenario on more pairs):
a stage to refit (noise twice too strong), the network to refit (a checkerboard), and the control, on 24 + 24 pairs
of 128². Each must accept the expected change first, close most of the gap, and leave the critic less able to tell
real from simulated; the control must accept nothing."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest
import torch

pytestmark = pytest.mark.slow
torch.set_num_threads(1)


def _bench() -> ModuleType:
    path = Path(__file__).resolve().parents[1] / "bench" / "bench_diagnose.py"
    spec = importlib.util.spec_from_file_location("camdegrade_bench_diagnose", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def bench() -> ModuleType:
    return _bench()


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
    assert row["fraction_closed"] >= 0.5, row
    assert row["critic_after"] < row["critic_before"] or row["critic_before"] <= 0.6, row


def test_the_control_accepts_nothing(bench: ModuleType) -> None:
    row = bench.run_scenario("control", 24, 24, 128, candidates=["noise", "tone", "blur"])
    assert row["accepted"] == [], row
    assert row["critic_before"] <= 0.6, row
