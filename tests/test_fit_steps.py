"""A fit is a loop of steps (issue 45): a step proposes on the training pairs, is judged on the validation pairs and
returns its evidence record, which the loop writes to ``fitted[step.name]``. Adding a step is one class, one
registry line and its test: shown here by a toy step registered for one fit and unregistered after it."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import pytest
import torch

from camdegrade import CameraProfile
from camdegrade.effects import Color
from camdegrade.fitting import FitConfig, fit_profile
from camdegrade.fitting.steps import STEPS, FitStep, PairedFit, Verdict, run_steps
from steps_for_tests import paired_fit, run_step


@dataclass(frozen=True)
class ToyGain(FitStep):
    """A global gain per channel (a diagonal colour matrix): proposed as the captures' mean over the profile's
    deterministic output on the training pairs, kept where it lowers the validation pairs' squared error."""

    name: ClassVar[str] = "toy_gain"
    floor: float = 0.0

    def propose(self, fit: PairedFit) -> Color | Verdict:
        cleans, captures = zip(*fit.train_pairs, strict=True)
        outputs = fit.profile.simulate(cleans, fit.seed, deterministic=True)
        gains = torch.stack(captures).mean((0, 2, 3)) / torch.stack(outputs).mean((0, 2, 3)).clamp_min(1e-6)
        if float((gains - 1).abs().max()) <= self.floor:
            return Verdict({"kept": False, "reason": "no gain above the floor"})
        return Color(torch.diag(gains))

    def judge(self, fit: PairedFit, stage: Color) -> dict[str, Any]:
        cleans, captures = zip(*fit.judge_pairs(8), strict=True)
        errors = []
        for profile in (fit.profile, fit.profile.with_effects(stage)):
            outputs = profile.simulate(cleans, fit.seed, deterministic=True)
            errors.append(sum(float((o - c).pow(2).mean()) for o, c in zip(outputs, captures, strict=True)))
        kept = errors[1] < errors[0]
        if kept:
            fit.profile = fit.profile.with_effects(stage)
        fit.say(f"toy gain: {'kept' if kept else 'dropped'}")
        return {"kept": kept, "gains": stage.matrix.diagonal().tolist(), "error_before": errors[0], "after": errors[1]}


def _pairs(count: int, gain: float, seed: int) -> list[tuple[torch.Tensor, torch.Tensor]]:
    generator = torch.Generator().manual_seed(seed)
    cleans = [torch.rand(3, 32, 32, generator=generator) * 0.8 + 0.1 for _ in range(count)]
    return [(clean, clean * gain) for clean in cleans]


@pytest.fixture
def toy_step():
    """ToyGain in the registry for one test, and out of it after."""
    STEPS[ToyGain.name] = ToyGain
    try:
        yield ToyGain
    finally:
        del STEPS[ToyGain.name]
    assert ToyGain.name not in STEPS  # unregistered: no other test sees it


def test_the_toy_step_proposes_on_training_pairs_and_is_judged_on_validation_pairs() -> None:
    lines: list[str] = []
    profile, record = run_step(ToyGain(), CameraProfile(None), _pairs(4, 0.8, 0), _pairs(3, 0.8, 1), lines.append)
    assert record["kept"] and record["after"] < record["error_before"] and lines == ["toy gain: kept"]
    assert [type(effect) for effect in profile.effects] == [Color]
    assert record["gains"] == pytest.approx([0.8] * 3, abs=1e-4)
    profile, record = run_step(ToyGain(floor=0.5), CameraProfile(None), _pairs(4, 0.8, 0), _pairs(3, 0.8, 1))
    assert record == {"kept": False, "reason": "no gain above the floor"} and not profile.effects


def test_a_registered_step_joins_a_recipe_by_name_and_the_loop_records_it(toy_step) -> None:
    recipe = FitConfig(epochs=1, crop=16, batch_size=4, crops_per_pair=2, val_fraction=0.34, arch="paper", width=8)
    recipe = recipe.replace(curves="none", steps=(("resolution", {"scale": 1.0}), ("toy_gain", {"floor": 0.01})))
    assert [step.name for step in recipe.steps] == ["resolution", "toy_gain"] and recipe.steps[1] == ToyGain(0.01)
    lines: list[str] = []
    profile = fit_profile(_pairs(6, 0.5, 2), recipe, log=lines.append)
    record = profile.fitted["toy_gain"]
    assert set(record) == {"kept", "gains", "error_before", "after"} and record["kept"] == (
        record["after"] < record["error_before"]
    )
    assert any(line.startswith("toy gain: ") for line in lines)
    assert profile.fitted["resolution"] == {"kept": False, "scale": 1.0} and "network" in profile.fitted
    assert (Color in {type(effect) for effect in profile.effects}) == record["kept"]


def test_an_unregistered_step_is_refused_by_name(toy_step) -> None:
    del STEPS[ToyGain.name]
    try:
        with pytest.raises(ValueError, match=r"steps: no fit step is named 'toy_gain'; the steps: \['resolution'"):
            FitConfig().replace(steps=("resolution", "toy_gain"))
    finally:
        STEPS[ToyGain.name] = ToyGain
    assert list(STEPS)[:6] == ["resolution", "effects", "resampler", "texture", "denoise", "response"]


def test_a_step_that_needs_a_network_records_that_there_is_none() -> None:
    fit = paired_fit(CameraProfile(None), _pairs(2, 0.8, 3), [])

    class NeedsNetwork(ToyGain):
        needs_network: ClassVar[bool] = True

    run_steps([NeedsNetwork()], fit)
    assert fit.records == {"toy_gain": {"kept": False, "reason": "no network"}} and not fit.profile.effects
