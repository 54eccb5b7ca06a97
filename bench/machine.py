"""The machine a bench ran on and its run, for its report (the CPU, how busy the machine was, the versions, workers,
seeds and times), and the one way a report is written."""

from __future__ import annotations

import json
import os
import platform
from pathlib import Path
from typing import Any

import torch

import camdegrade
from camdegrade.network.inference import native_bfloat16


def cpu_description() -> str:
    """The CPU's model name (Linux), the vector ISA torch dispatches to, and whether bfloat16 is native."""
    model = platform.processor() or platform.machine()
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.exists():
        names = [line.split(":", 1)[1].strip() for line in cpuinfo.read_text().splitlines() if "model name" in line]
        model = names[0] if names else model
    native = "native bfloat16" if native_bfloat16(torch.device("cpu")) else "no native bfloat16"
    return f"{model}, {torch.backends.cpu.get_cpu_capability()}, {native}"


def load_text() -> str:
    """The machine's load averages (1, 5, 15 min; Linux), which say how busy it was while timing."""
    one, five, fifteen = os.getloadavg()
    return f"load average {one:.2f} {five:.2f} {fifteen:.2f} on {os.cpu_count()} CPUs"


def run_facts(workers: int, seeds: list[int], wall: float, cpu: float) -> dict[str, Any]:
    """The versions, worker processes and seeds of a run, and its wall and CPU time (seconds, 0.1 s)."""
    return {
        "camdegrade": camdegrade.__version__,
        "torch": torch.__version__,
        "workers": workers,
        "seeds": seeds,
        "wall_seconds": round(wall, 1),
        "cpu_seconds": round(cpu, 1),
    }


def write_json(path: Path, record: dict[str, Any]) -> None:
    """``record`` as indented JSON at ``path`` (its folder made; numbers of numpy or torch written as floats)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(record, indent=2, default=float) + "\n")
    print(f"wrote {path}")
