"""The diagnosis on REAL sensor noise (PolyU, CC15, SIDD: clean = mean of many frames, real = one frame).

A profile with no noise stage (the identity) must be diagnosed as missing ``noise`` (a significant reduction of
the held-out gap), and the fitted noise level must match the measured residual std within 20 %. Both levels are
measured on the flat pixels of all the subset's pairs (the flattest half of each clean image, where the
residual is noise rather than residual misalignment or demosaicking at edges): measured = std of
``real − clean``, fitted = std of ``sim − sim_mean`` for the profile the diagnosis returns. Skipped when the
shared real-pairs folder is absent.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from camdegrade.diagnose import DiagnosisReport, diagnose
from camdegrade.diagnose.stats import flat_mask
from camdegrade.fitting.pairs import discover_pairs, filter_pairs, load_pair
from camdegrade.fitting.pairset import simulate
from camdegrade.profile import CameraProfile

pytestmark = [pytest.mark.realdata, pytest.mark.slow]
torch.set_num_threads(1)

#: subset → (centre crop, at most this many pairs). SIDD is dark and noisy: its noise fit needs whole images.
SUBSETS = {"polyu_real_noise": (128, 40), "cc15_nam_real_noise": (128, 15), "sidd_samples": (512, 12)}


def _pairs(folder: Path, subset: str) -> list[tuple[torch.Tensor, torch.Tensor]]:
    crop, count = SUBSETS[subset]
    pairs = filter_pairs(discover_pairs(folder / "pairs.csv").pairs, subset=subset)
    pairs = pairs[:: max(1, len(pairs) // count)][:count]
    out = []
    for pair in pairs:
        clean, captured = load_pair(pair)
        height, width = clean.shape[-2:]
        side = min(crop, height, width)
        top, left = (height - side) // 2, (width - side) // 2
        window = (slice(None), slice(top, top + side), slice(left, left + side))
        out.append((clean[window].float() / 255, captured[window].float() / 255))
    return out


def _levels(report: DiagnosisReport, pairs: list[tuple[torch.Tensor, torch.Tensor]]) -> tuple[float, float]:
    cleans = [clean for clean, _ in pairs]
    masks = [flat_mask(clean) for clean in cleans]
    measured = torch.cat([(real - clean)[:, m].flatten() for (clean, real), m in zip(pairs, masks, strict=True)])
    assert report.profile is not None
    noisy = simulate(report.profile, cleans, 1)
    mean = simulate(report.profile, cleans, 1, deterministic=True)
    fitted = torch.cat([(n - s)[:, m].flatten() for n, s, m in zip(noisy, mean, masks, strict=True)])
    return float(measured.std() * 255), float(fitted.std() * 255)


@pytest.fixture(scope="module")
def reports(real_pairs_dir: Path) -> dict[str, tuple[DiagnosisReport, list]]:
    out = {}
    for subset in SUBSETS:
        pairs = _pairs(real_pairs_dir, subset)
        out[subset] = (diagnose(CameraProfile(None, [], name="no-noise"), pairs, seed=0), pairs)
    return out


@pytest.mark.parametrize("subset", list(SUBSETS))
def test_missing_noise_is_named(reports: dict, subset: str) -> None:
    report, _ = reports[subset]
    assert report.added and report.added[0] == "noise", report.verdict
    assert report.effects[0]["name"] == "noise" and report.effects[0]["significant"]


@pytest.mark.parametrize("subset", list(SUBSETS))
def test_fitted_noise_level_matches_the_residual(reports: dict, subset: str) -> None:
    report, pairs = reports[subset]
    measured, fitted = _levels(report, pairs)
    assert fitted == pytest.approx(measured, rel=0.2), (measured, fitted)
