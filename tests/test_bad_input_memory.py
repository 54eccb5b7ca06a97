"""Memory under hostile images (issue 17): ``camdegrade apply`` on a decompression bomb and on a large truncated image
refuses them within ~200 MB of peak memory, measured in a child process: ``getrusage``'s peak RSS once torch and
camdegrade are imported and warmed up (the peak restarted from the current RSS where Linux allows), against the peak
at the end. The imports alone take several hundred MB (torch), which is why the growth is what is bounded. The child
also caps its address space, so a regression fails instead of swapping."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from bad_inputs import png_with_rows
from profiles_for_tests import deterministic_profile

BUDGET_MB = 200

CHILD = """
import json, resource, sys
import torch
import camdegrade.io, camdegrade.transform, camdegrade.profile
from camdegrade.__main__ import main

def peak_mb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024

with open("/proc/self/status") as status:
    virtual = next(int(line.split()[1]) * 1024 for line in status if line.startswith("VmSize:"))
resource.setrlimit(resource.RLIMIT_AS, (virtual + 2 * 1024**3, resource.RLIM_INFINITY))
torch.set_num_threads(1)
main(["apply", sys.argv[1], sys.argv[2], sys.argv[3] + "/warm-up.png"])  # every lazy import and first-call cost
try:  # Linux: restart the peak from the current RSS, so the warm-up's own peak cannot hide growth
    with open("/proc/self/clear_refs", "w") as clear:
        clear.write("5")
except OSError:
    pass
before = peak_mb()
try:
    status = main(["apply", sys.argv[1], sys.argv[4], sys.argv[3] + "/out.png"])
except BaseException as error:
    status = repr(error)
print(json.dumps({"status": status, "before_mb": before, "after_mb": peak_mb()}))
"""


@pytest.mark.slow
@pytest.mark.parametrize(
    "name, height, width, rows, message",
    [
        ("bomb.png", 12000, 12000, 50, "144000000 pixels"),  # 1.8 KB on disk; Pillow alone decodes 432 MB
        ("truncated.png", 8000, 8000, 8, "truncated"),  # a 64-Mpixel header with 8 rows of data
    ],
)
def test_apply_refuses_within_the_memory_budget(
    tmp_path: Path, name: str, height: int, width: int, rows: int, message: str
) -> None:
    profile = deterministic_profile().save(tmp_path / "p.safetensors")
    small = png_with_rows(tmp_path / "small.png", 32, 32, rows=32)
    hostile = png_with_rows(tmp_path / name, height, width, rows=rows)
    result = subprocess.run(
        [sys.executable, "-c", CHILD, str(profile), str(small), str(tmp_path), str(hostile)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    report = json.loads(result.stdout.strip().splitlines()[-1])
    grown = report["after_mb"] - report["before_mb"]
    print(f"{name}: RSS {report['before_mb']:.0f} MB after the imports, peak grew {grown:.1f} MB while refusing")
    assert report["status"] == 1, result.stderr[-2000:]
    assert message in result.stderr and len(result.stderr.strip().splitlines()) == 1, result.stderr[-2000:]
    assert grown < BUDGET_MB
    assert not (tmp_path / "out.png").exists()
