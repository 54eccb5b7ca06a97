"""``make bench`` (bench/run.py) runs every bench script but the long research ones, which ``--all`` adds."""

from __future__ import annotations

from pathlib import Path

import pytest

from conftest import REPOSITORY, load_script

run = load_script("bench/run.py", "bench_run")


def _ran(monkeypatch: pytest.MonkeyPatch, argv: list[str]) -> list[str]:
    ran: list[str] = []

    class Done:
        returncode = 0

    def fake_run(command, check):
        ran.append(Path(command[1]).name)
        return Done()

    monkeypatch.setattr(run.subprocess, "run", fake_run)
    assert run.main(argv) == 0
    return ran


def test_the_long_benches_are_scripts_of_bench() -> None:
    assert set(run.LONG) <= {path.name for path in (REPOSITORY / "bench").glob("bench_*.py")}


def test_make_bench_leaves_out_the_long_benches_and_all_adds_them(monkeypatch: pytest.MonkeyPatch) -> None:
    every = sorted(path.name for path in (REPOSITORY / "bench").glob("bench_*.py"))
    default = _ran(monkeypatch, [])
    assert default == [name for name in every if name not in run.LONG] and "bench_transform.py" in default
    assert _ran(monkeypatch, ["--all"]) == every
