"""The machine a bench ran on, for its report: the CPU and how busy the machine was."""

from __future__ import annotations

import os
import platform
from pathlib import Path

import torch

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
