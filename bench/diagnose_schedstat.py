"""``camdegrade diagnose`` run as the command line runs it, with where its time went read from Linux's per-thread
scheduler statistics (``/proc/thread-self/schedstat``: on a CPU, waiting for one, and, the rest, blocked).

On a machine other processes share, a command's wall time holds the time its threads waited for a CPU the others
held. This script separates it: every task that ``side_by_side`` runs (a round's changes, a critic's two folds) is
timed in its own thread, and the main thread for the rest. What the wall would be with the machine to itself is
estimated as the main thread's own time (on a CPU, or blocked outside the tasks: reading, writing) plus, per
``side_by_side`` call, the tasks' time on a CPU or blocked (waiting for the GIL or another lock: that stays on an idle
machine) scheduled in their order onto the call's worker threads, as its thread pool does. Used by
``bench_diagnose_time.py --schedstat``; run alone::

    python bench/diagnose_schedstat.py PROFILE PAIRS REPORT [--threads 2]

Prints one JSON line (seconds). Linux only.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any


def process_age() -> float:
    """Seconds since this process started (the interpreter's own start included)."""
    with open("/proc/self/stat") as stat:
        started = int(stat.read().rsplit(")", 1)[1].split()[19]) / os.sysconf("SC_CLK_TCK")
    with open("/proc/uptime") as uptime:
        return float(uptime.read().split()[0]) - started


def schedstat() -> tuple[float, float]:
    """This thread's seconds on a CPU and waiting for one, since it started."""
    with open("/proc/thread-self/schedstat") as stats:
        on_cpu, waiting, _ = stats.read().split()
    return int(on_cpu) / 1e9, int(waiting) / 1e9


def makespan(durations: Sequence[float], workers: int) -> float:
    """The end of the last task when each goes, in order, to the first worker free."""
    free = [0.0] * max(1, workers)
    for duration in durations:
        free[free.index(min(free))] += duration
    return max(free)


class Recorder:
    """Wraps ``side_by_side``: per call, its wall time and each task's (wall, on a CPU, waiting for one)."""

    def __init__(self, side_by_side: Callable) -> None:
        self.side_by_side = side_by_side
        self.calls: list[dict[str, Any]] = []

    def __call__(self, calls: Sequence[Callable]) -> list:
        import torch

        tasks: list[tuple[float, float, float]] = [(0.0, 0.0, 0.0)] * len(calls)

        def timed(index: int, call: Callable) -> Callable:
            def run() -> Any:
                before, started = schedstat(), time.perf_counter()
                out = call()
                after = schedstat()
                tasks[index] = (time.perf_counter() - started, after[0] - before[0], after[1] - before[1])
                return out

            return run

        workers = min(len(calls), torch.get_num_threads())
        started = time.perf_counter()
        out = self.side_by_side([timed(index, call) for index, call in enumerate(calls)])
        self.calls.append({"workers": workers, "wall": time.perf_counter() - started, "tasks": tasks})
        return out


def install() -> Recorder:
    """A :class:`Recorder` in place of ``side_by_side`` in every module loaded that holds it, and in
    ``camdegrade._runtime.threads`` for those that import it later."""
    from camdegrade._runtime import threads

    original = threads.side_by_side
    recorder = Recorder(original)
    for module in list(sys.modules.values()):
        if getattr(module, "side_by_side", None) is original:
            module.side_by_side = recorder
    return recorder


def summary(recorder: Recorder, wall: float) -> dict[str, float]:
    main_cpu, main_waiting = schedstat()
    in_calls = sum(call["wall"] for call in recorder.calls)
    tasks = [task for call in recorder.calls for task in call["tasks"]]
    task_cpu, task_waiting = sum(t[1] for t in tasks), sum(t[2] for t in tasks)
    task_blocked = sum(t[0] - t[1] - t[2] for t in tasks)
    main_blocked = max(0.0, wall - in_calls - main_cpu - main_waiting)
    parallel = sum(makespan([t[0] - t[2] for t in call["tasks"]], call["workers"]) for call in recorder.calls)
    return {
        "wall": round(wall, 1),
        "cpu": round(main_cpu + task_cpu, 1),
        "waiting_for_cpu": round(main_waiting + task_waiting, 1),
        "tasks_blocked": round(task_blocked, 1),
        "main_blocked_outside_tasks": round(main_blocked, 1),
        "in_side_by_side": round(in_calls, 1),
        "idle_machine_estimate": round(main_cpu + main_blocked + parallel, 1),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("profile")
    parser.add_argument("pairs")
    parser.add_argument("report")
    parser.add_argument("--threads", default="2")
    args = parser.parse_args(argv)
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # as the command line sets it, before torch loads
    recorder = install()
    import camdegrade.cli

    command = ["diagnose", args.profile, args.pairs, "--threads", args.threads, "--json", args.report, "--quiet"]
    status = camdegrade.cli.main(command)
    print(json.dumps(summary(recorder, process_age())))
    return status


if __name__ == "__main__":
    sys.exit(main())
