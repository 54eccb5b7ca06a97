"""A change whose reduction is too small to count is not bootstrapped (issue 44: the log printed "± nan" on every such
line): the log says why it has no standard error, and the JSON records the reduction it needed beside a null SE."""

from __future__ import annotations

import math
import re

import torch

from camdegrade.diagnose import diagnose
from camdegrade.diagnose.attribution.changes import Change
from camdegrade.effects import Noise, Vignetting
from camdegrade.profile import CameraProfile
from camdegrade.sim import VirtualCamera
from effects_images import patch_chart

torch.set_num_threads(1)


def _pairs(count: int, seed: int) -> list[tuple[torch.Tensor, torch.Tensor]]:
    camera = VirtualCamera([Vignetting(k1=-0.2), Noise(a=0.002)], scale=1.0)
    generator = torch.Generator().manual_seed(seed + 1)
    cleans = [patch_chart(64, patches=2, seed=seed * 100 + index) for index in range(count)]
    with torch.no_grad():
        return [(clean, camera(clean[None], generator=generator)[0]) for clean in cleans]


def test_a_reduction_too_small_to_count_says_so_instead_of_nan() -> None:
    lines: list[str] = []
    profile = CameraProfile(None, [Noise(a=0.002)])  # lacks the camera's vignetting: a gap to try changes on
    report = diagnose(
        profile,
        _pairs(4, seed=5),
        held_out=_pairs(4, seed=6),
        candidates=["blur"],
        kinds=["add"],
        critic=False,
        log=lines.append,
    )
    change_lines = [line for line in lines if "(reduction " in line]
    assert change_lines and not any("nan" in line for line in change_lines), change_lines
    unbootstrapped = [row for row in report.changes if row["reduction_se"] is None and "error" not in row]
    assert unbootstrapped, report.changes
    for row in unbootstrapped:
        assert row["reduction"] < row["reduction_needed"], row
        label = f"{row['kind']} {row['name']}"
        said = [line for line in change_lines if line.strip().startswith(label + ":")]
        assert said and re.search(r"not bootstrapped: below the \d+\.\d\d that can count", said[0]), said


def test_the_reduction_text_never_prints_nan() -> None:
    change = Change("add", "tone", None, None, 3.0, reduction=0.05)
    assert change.reduction_text() == "+0.05"  # not evaluated: no threshold either
    change.reduction_needed = 0.5
    assert change.reduction_text() == "+0.05; not bootstrapped: below the 0.50 that can count"
    change.reduction_se = 0.12
    assert change.reduction_text() == "+0.05 ± 0.12" and not math.isnan(change.reduction_se)
