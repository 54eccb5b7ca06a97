"""The record and log line of an evidence stage judged by one statistic (the JPEG and cfa stages share them)."""

from __future__ import annotations

from camdegrade.fitting.evidence.statistic import StatisticJudgement


def test_a_dropped_stage_records_the_three_values_and_what_it_leaves_of_the_gap() -> None:
    judged = StatisticJudgement(
        real=1.2, without=1.0, within=1.15, kept=False, gain=0.01234, pairs=10, label="validation"
    )
    record = judged.record("block_edges", "the block-edge gap")
    assert list(record) == [
        "block_edges_real",
        "block_edges_without",
        "block_edges_with",
        "evidence",
        "relative_mse_gain",
        "reason",
    ]
    assert record["relative_mse_gain"] == 0.0123 and record["evidence"] == "validation"
    assert record["reason"] == "it leaves 0.050 of the block-edge gap of 0.200"
    assert judged.line_end() == "relative MSE gain 1.23% on 10 validation pair(s) -> dropped"


def test_a_kept_stage_gives_no_reason() -> None:
    judged = StatisticJudgement(real=0.4, without=1.0, within=0.45, kept=True, gain=0.2, pairs=3, label="training")
    assert "reason" not in judged.record("trace", "the mosaic trace's gap")
    assert judged.line_end().endswith("-> kept")
