"""Smoke test of ``experiments/reproduce_paper.py --quick``: the paper's ordering holds on captured test images."""

from __future__ import annotations

import json

import pytest
import torch

from conftest import load_script


def load_example():
    return load_script("experiments/reproduce_paper.py", "reproduce_paper")


def test_scenes_are_seeded_and_in_range():
    example = load_example()
    first = example.render_set([0, 4, -1, None], "train", 64, seed=3)
    again = example.render_set([0, 4, -1, None], "train", 64, seed=3)
    assert first.shape == (4, 3, 64, 64) and first.dtype == torch.uint8
    assert torch.equal(first, again)


@pytest.mark.slow
def test_quick_run_orders_source_ours_oracle_on_captures(tmp_path):
    """One seed, ~2.2 CPU-minutes (~3 min wall on 2 shared cores). Seed 0 gives, on 300 captured test images:
    source 21.0 %, zero-shot 44.0 %, unsupervised 51.3 %, oracle 63.7 %; the closest margin is 12 points (≈ 36
    images), far above run-to-run noise for a fixed seed, so no tolerance is needed. Smaller settings (80 images per
    class, 8 epochs) undertrain the oracle, which sees half as many images per epoch as the union rows, and break
    the ordering: keep ``QUICK`` at least this large."""
    example = load_example()
    threads = torch.get_num_threads()
    try:
        results = example.main(["--quick", "--seeds", "0", "--out", str(tmp_path)])
    finally:
        torch.set_num_threads(threads)
    captured = {row: columns["captured"]["mean"] for row, columns in results["table"].items()}
    assert captured["source"] < captured["zero-shot"] <= captured["oracle"], captured
    assert captured["source"] < captured["unsupervised"] <= captured["oracle"], captured
    saved = json.loads((tmp_path / "results.json").read_text())
    assert saved["table"] == results["table"]
