"""The diagnosis on REAL sensor noise (PolyU, CC15, SIDD: clean = mean of many frames, real = one frame).

A profile with no noise stage (the identity) must be diagnosed as missing ``noise`` (adding it the first accepted
change), and the profile the diagnosis returns must give the noise the held-out captures show where the clean
image is flat: the pooled std of the image minus its 17×17 mean, simulated against real, within 15 % (30 % for
SIDD's mixed phones). That is what the diagnosis matches; on PolyU the fitted stage adds somewhat less than
``real − clean`` holds, because the one frame is smoother than the mean of many (see docs/diagnosis.md).
Each pair is cut to its 256² window with the most flat pixels (noise is measured only there). Skipped when the
shared real-pairs folder is absent.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from camdegrade.diagnose import DiagnosisReport
from conftest import load_script

pytestmark = [pytest.mark.realdata, pytest.mark.slow]
torch.set_num_threads(1)

#: How close the returned profile's noise must come to the captures'. SIDD's crops come from different phones whose
#: noise differs 4.7× from image to image, and the stage is fitted on the calibration half alone (6 crops, the
#: noisier phones: it comes out 25 % high over all 12).
TOLERANCE = {"polyu_real_noise": 0.15, "cc15_nam_real_noise": 0.15, "sidd_samples": 0.3}


EXAMPLE = load_script("experiments/diagnose_real_noise.py", "camdegrade_diagnose_real_noise_example")


@pytest.fixture(scope="module")
def reports(real_pairs_dir: Path) -> dict[str, tuple[DiagnosisReport, list]]:
    out = {}
    for subset in TOLERANCE:
        pairs = EXAMPLE.subset_pairs(real_pairs_dir, subset)
        out[subset] = (EXAMPLE.diagnose_without_noise(pairs), pairs)
    return out


@pytest.mark.parametrize("subset", list(TOLERANCE))
def test_missing_noise_is_named(reports: dict, subset: str) -> None:
    report, _ = reports[subset]
    assert report.accepted and report.accepted[0] == "add noise", report.verdict
    assert report.effects[0]["name"] == "noise" and report.effects[0]["significant"]
    assert next(w for w in report.where if w["axis"] == "noise")["significant"]


@pytest.mark.parametrize("subset", list(TOLERANCE))
def test_the_returned_profile_gives_the_captures_noise(reports: dict, subset: str) -> None:
    report, pairs = reports[subset]
    real, simulated, pixels = EXAMPLE.flat_noise(report.profile, pairs)
    assert pixels > 50_000
    assert simulated == pytest.approx(real, rel=TOLERANCE[subset]), (real, simulated)
