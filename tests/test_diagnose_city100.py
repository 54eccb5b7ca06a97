"""The diagnosis on REAL City100 captures: it must see what a person sees at 1:1.

The 16 held-out City100 iPhone X scenes (056–070, 098), each cut to its 256² window with the most flat pixels (the
noise statistics rest on flat pixels; a centre crop of a city scene holds almost none). The profile as shipped before
the flat-region noise fit (``tests/fixtures/city100-iphonex-2026-11-23.safetensors``: its noise is 4.7× the camera's
and banded) must be flagged: its noise stage too strong and banded, refitting or removing it the first accepted
change, and the critic less sure after it. The profile refitted since (the paper-network built-in as shipped until
2026-11-27, ``PAPER_BUILT_IN``) must show no significant noise finding, and be named by its network's 4-pixel grid.
Skipped when the shared real-pairs folder is absent.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from camdegrade import CameraDegrade, load_profile
from camdegrade._support.pixels import as_unit
from camdegrade.diagnose import DiagnosisReport, diagnose
from camdegrade.functional.analysis.images import flattest_window
from camdegrade.measures.critic import critic_test
from conftest import PAPER_BUILT_IN, load_script

pytestmark = [pytest.mark.realdata, pytest.mark.slow]
torch.set_num_threads(1)

FIXTURE = Path(__file__).resolve().parent / "fixtures" / "city100-iphonex-2026-11-23.safetensors"
SIDE = 256
NOISE_AXES = ("noise", "noise_correlation", "banding")


def _example():
    return load_script("experiments/diagnose_city100.py", "camdegrade_diagnose_city100_example")


def _flattest_crop(clean: torch.Tensor, captured: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    window, _ = flattest_window(clean.float() / 255, SIDE)
    return clean[(slice(None), *window)], captured[(slice(None), *window)]


@pytest.fixture(scope="module")
def crops(real_pairs_dir: Path) -> list[tuple[torch.Tensor, torch.Tensor]]:
    return [_flattest_crop(clean, captured) for clean, captured in _example().held_out_pairs(real_pairs_dir)]


@pytest.fixture(scope="module")
def before(crops: list) -> DiagnosisReport:
    """Stages removed or refitted (adding effects or refitting the network is not what this is about)."""
    return diagnose(FIXTURE, crops, candidates=[], kinds=("remove", "refit"), seed=0)


@pytest.fixture(scope="module")
def after(crops: list) -> DiagnosisReport:
    """Where the gap lies, and whether refitting or removing the noise stage would help."""
    return diagnose(PAPER_BUILT_IN, crops, candidates=[], kinds=("remove", "refit"), seed=0, critic=False)


def _where(report: DiagnosisReport) -> dict[str, dict]:
    return {entry["axis"]: entry for entry in report.where}


def test_the_old_noise_stage_is_flagged_too_strong_and_banded(before: DiagnosisReport) -> None:
    where = _where(before)
    assert all(where[axis]["significant"] for axis in NOISE_AXES), before.where
    assert before.where[0]["axis"] in NOISE_AXES
    assert "flat pixels" in where["noise"]["finding"]
    assert before.accepted and before.accepted[0] in ("refit noise", "remove noise"), before.accepted
    first = next(change for change in before.changes if f"{change['kind']} {change['name']}" == before.accepted[0])
    assert "× the camera's noise and banded" in first["description"], first
    assert "noise stage is" in before.verdict and "× the camera's noise" in before.verdict, before.verdict


def test_the_critic_is_less_sure_once_the_noise_is_fixed(before: DiagnosisReport) -> None:
    critic = before.critic
    assert critic["before"]["accuracy"] > 0.9
    assert critic["after"]["accuracy"] < critic["before"]["accuracy"] - 0.03, critic


def test_the_refitted_profile_shows_no_noise_finding(after: DiagnosisReport) -> None:
    """The noise level is no longer significant (row and column means stay 1.3–1.5× the camera's on these crops,
    from the network and the noise's correlation, not a banding stage: the built-in has none)."""
    assert not _where(after)["noise"]["significant"], after.where
    assert not any(label.endswith(" noise") for label in after.accepted), after.accepted


def test_the_built_in_is_named_by_its_4_pixel_grid(after: DiagnosisReport) -> None:
    """What a person sees beside the captures: the built-in's network prints a 4-pixel grid (7.7× the camera's on
    the 8 held-out whole frames of experiments/diagnose_city100.py), and the verdict names it."""
    grid = next(entry for entry in after.visible if entry["look"] == "grid")
    assert grid["significant"] and grid["before"]["ratio"] > 2, grid
    assert "What a person sees: the simulation carries a 4-pixel grid" in after.verdict, after.verdict


def test_the_sampled_profile_is_no_easier_to_tell_apart_than_without_its_noise(crops: list) -> None:
    """The learned critic, trained on 8 scenes and scored on the other 8: the built-in's samples are no easier to
    tell from the captures than its deterministic part (its noise adds nothing the critic can use), while the old
    profile's noise gives every patch away."""
    current = load_profile(PAPER_BUILT_IN)
    cleans = [as_unit(clean) for clean, _ in crops]
    reals = [as_unit(real) for _, real in crops]

    def accuracy(profile) -> float:
        sims = [as_unit(CameraDegrade(profile, seed=i)(clean)) for i, (clean, _) in enumerate(crops)]
        fit, check = slice(0, None, 2), slice(1, None, 2)
        return critic_test((cleans[fit], reals[fit], sims[fit]), (cleans[check], reals[check], sims[check]), 0).accuracy

    sampled, deterministic = accuracy(current), accuracy(current.without_randomness())
    assert sampled <= deterministic + 0.05, (sampled, deterministic)
    assert accuracy(load_profile(FIXTURE)) > 0.95
