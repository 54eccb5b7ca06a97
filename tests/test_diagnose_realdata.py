"""The diagnosis on REAL sensor noise (PolyU, CC15, SIDD: clean = mean of many frames, real = one frame).

A profile with no noise stage (the identity) must be diagnosed as missing ``noise`` (adding it the first accepted
change), and the profile the diagnosis returns must give the noise the held-out captures show where the clean
image is flat: the pooled std of the image minus its 17×17 mean, simulated against real, within 15 % (30 % for
SIDD's mixed phones). That is what the diagnosis matches; on PolyU the fitted stage adds somewhat less than
``real − clean`` holds, because the one frame is smoother than the mean of many (see docs/diagnosis.md).
Each pair is cut to its 256² window with the most flat pixels (noise is measured only there). Skipped when the shared real-pairs folder is absent.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
import torch.nn.functional as F

from camdegrade.diagnose import DiagnosisReport, diagnose
from camdegrade.fitting.pairs import discover_pairs, filter_pairs, load_pair
from camdegrade.fitting.pairset import simulate
from camdegrade.functional.analysis import flat_mask
from camdegrade.functional.noise_stats import measure_set
from camdegrade.profile import CameraProfile

pytestmark = [pytest.mark.realdata, pytest.mark.slow]
torch.set_num_threads(1)

#: subset → at most this many pairs (evenly chosen).
SUBSETS = {"polyu_real_noise": 24, "cc15_nam_real_noise": 15, "sidd_samples": 12}
#: How close the returned profile's noise must come to the captures'. SIDD's crops come from different phones whose
#: noise differs 4.7× from image to image, and the stage is fitted on the calibration half alone (6 crops, the
#: noisier phones: it comes out 25 % high over all 12).
TOLERANCE = {"polyu_real_noise": 0.15, "cc15_nam_real_noise": 0.15, "sidd_samples": 0.3}
SIDE = 256


def _flattest(clean: torch.Tensor, captured: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    side = min(SIDE, *clean.shape[-2:])
    pooled = F.avg_pool2d(flat_mask(clean).float()[None, None], side, stride=8)[0, 0]
    top, left = divmod(int(pooled.argmax()), pooled.shape[1])
    window = (slice(None), slice(top * 8, top * 8 + side), slice(left * 8, left * 8 + side))
    return clean[window], captured[window]


def _pairs(folder: Path, subset: str) -> list[tuple[torch.Tensor, torch.Tensor]]:
    count = SUBSETS[subset]
    pairs = filter_pairs(discover_pairs(folder / "pairs.csv").pairs, subset=subset)
    pairs = pairs[:: max(1, len(pairs) // count)][:count]
    out = []
    for pair in pairs:
        clean, captured = load_pair(pair)
        out.append(_flattest(clean.float() / 255, captured.float() / 255))
    return out


@pytest.fixture(scope="module")
def reports(real_pairs_dir: Path) -> dict[str, tuple[DiagnosisReport, list]]:
    out = {}
    for subset in SUBSETS:
        pairs = _pairs(real_pairs_dir, subset)
        profile = CameraProfile(None, [], name="no-noise")
        out[subset] = (diagnose(profile, pairs, candidates=["noise", "blur", "jpeg"], seed=0, critic=False), pairs)
    return out


@pytest.mark.parametrize("subset", list(SUBSETS))
def test_missing_noise_is_named(reports: dict, subset: str) -> None:
    report, _ = reports[subset]
    assert report.accepted and report.accepted[0] == "add noise", report.verdict
    assert report.effects[0]["name"] == "noise" and report.effects[0]["significant"]
    assert next(w for w in report.where if w["axis"] == "noise")["significant"]


@pytest.mark.parametrize("subset", list(SUBSETS))
def test_the_returned_profile_gives_the_captures_noise(reports: dict, subset: str) -> None:
    report, pairs = reports[subset]
    cleans, reals = [clean for clean, _ in pairs], [real for _, real in pairs]
    masks = [flat_mask(clean) for clean in cleans]
    assert report.profile is not None
    simulated = measure_set(simulate(report.profile, cleans, 1), cleans, masks).pooled_std()
    real = measure_set(reals, cleans, masks).pooled_std()
    assert simulated == pytest.approx(real, rel=TOLERANCE[subset]), (real, simulated)
