"""The learned texture stage as a step (issue 43): the unpaired fit's last, asked for by name, fitted after the
named stages and kept only by the held-out halves' judgement, whose statistics rule is the named stages' own (a
change counts only beyond SIGNIFICANCE split-half standard errors); and the paired fit's recipe option, kept by the
validation pairs."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from camdegrade import CameraProfile
from camdegrade.cli.fit import _unpaired_effects
from camdegrade.effects import LearnedTexture, Noise
from camdegrade.fitting import FitConfig
from camdegrade.fitting.steps.learned import MAX_PSNR_LOSS_DB, LearnedTexturePaired
from camdegrade.fitting.two_sample.gate import CRITIC_SLACK, Judgement
from camdegrade.fitting.two_sample.step import LearnedTextureMatch
from camdegrade.fitting.unpaired import fit as unpaired_fit
from camdegrade.fitting.unpaired import fit_unpaired
from camdegrade.fitting.unpaired.fit import UNPAIRED_EFFECTS, UNPAIRED_OPTIONAL, check_unpaired_effects
from camdegrade.fitting.unpaired.judges import SIGNIFICANCE
from camdegrade.synthetic import dead_leaves_images
from steps_for_tests import run_step

torch.set_num_threads(1)


def _row(distance: float, critic: float) -> dict:
    return {"distance": distance, "critic": critic}


@pytest.mark.parametrize(
    ("change", "error", "critic_after", "keep"),
    [
        (0.03, 0.02, 0.64, True),  # farther by 1.5 standard errors: within what the images' content moves it
        (0.03, 0.005, 0.64, False),  # the same change 6 standard errors out: farther
        (-0.05, 0.02, 0.64, True),  # the critic falls
        (-0.05, 0.02, 0.73, False),  # neither the critic falls nor do the statistics move beyond their error
        (-0.05, 0.02, 0.74, False),  # the same, the critic a little easier
        (-0.08, 0.02, 0.74, True),  # closer by 4 standard errors, the critic no easier than its slack
        (-0.08, 0.02, 0.80, False),  # closer, but the critic finds it easier
    ],
)
def test_the_gate_wants_one_measure_better_and_neither_worse_than_its_noise(
    change: float, error: float, critic_after: float, keep: bool
) -> None:
    judgement = Judgement(without=_row(0.30, 0.73), with_stage=_row(0.30 + change, critic_after), change_error=error)
    assert judgement.keep is keep
    assert judgement.not_farther is (change <= SIGNIFICANCE * error)
    assert judgement.not_easier is (critic_after <= 0.73 + CRITIC_SLACK)
    assert judgement.to_dict()["keep"] is keep


def test_the_learned_stage_is_the_unpaired_fits_last_default_stage() -> None:
    assert UNPAIRED_EFFECTS[-1] == "learned_texture" and UNPAIRED_OPTIONAL == ()
    assert [label for label, step in unpaired_fit.UNPAIRED_STEPS if isinstance(step, LearnedTextureMatch)] == [
        "learned texture: trained on half A, judged on B",
        "learned texture: trained on half B, judged on A",
        "learned texture: trained on all",
    ]
    assert check_unpaired_effects(["noise", "learned_texture"]) == ["noise", "learned_texture"]
    with pytest.raises(ValueError, match=r"effects must be names from .*'learned_texture'.*got 'texture'"):
        check_unpaired_effects(["texture"])


@pytest.mark.slow
def test_the_step_runs_last_trains_after_the_named_stages_and_records_its_judgement(
    monkeypatch, learned_texture
) -> None:
    """A tiny fit (8 grainy captures of 96², 8 clean images, 4 training steps): the step's record holds both
    halves' judgements (or the first, refused) and a training per half plus one on all where kept; the profile
    has the stage last exactly where the record says kept, and the same seed gives the same profile."""
    steps = tuple(
        (label, replace(step, steps=4) if isinstance(step, LearnedTextureMatch) else step)
        for label, step in unpaired_fit.UNPAIRED_STEPS
    )
    assert isinstance(steps[-1][1], LearnedTextureMatch)
    monkeypatch.setattr(unpaired_fit, "UNPAIRED_STEPS", steps)
    camera = CameraProfile(None, [Noise(b=(5.0 / 255) ** 2, linear=False)])
    captures = camera.simulate([image.float() / 255 for image in dead_leaves_images(8, 96, seed=2)], 7, eight_bit=True)
    cleans = list(dead_leaves_images(8, 96, seed=1))
    profiles = [fit_unpaired(captures, cleans, effects=("learned_texture",)) for _ in range(2)]
    record = profiles[0].fitted["effects"]["learned_texture"]
    kept = record["kept"]
    assert len(record["judgements"]) == (2 if record["judgements"][0]["keep"] else 1)
    assert kept == all(judgement["keep"] for judgement in record["judgements"]) and len(record["judgements"]) >= 1
    assert record["trainings"] == len(record["judgements"]) + (1 if kept else 0)
    assert profiles[0].effect_names == (["learned_texture"] if kept else [])
    first, again = (
        {key: value for effect in p.effects for key, value in effect.state_dict().items()} for p in profiles
    )
    assert first.keys() == again.keys() and all(torch.equal(first[key], again[key]) for key in first)


def test_the_paired_recipe_offers_it_last_and_leaves_it_out_by_default() -> None:
    assert FitConfig().option("learned_texture") == "none"
    recipe = FitConfig().replace(learned_texture="critic")
    assert recipe.steps[-1] == LearnedTexturePaired() and recipe.option("learned_texture") == "critic"
    assert "learned_texture" not in [step.name for step in recipe.replace(learned_texture="none").steps]
    assert _unpaired_effects(("noise", "blur"), "critic") == ["noise", "blur", "learned_texture"]
    assert _unpaired_effects(("noise", "learned_texture"), "none") == ["noise"]
    assert _unpaired_effects(("noise", "learned_texture"), None) == ("noise", "learned_texture")


@pytest.mark.slow
def test_the_paired_step_is_kept_where_the_validation_critic_falls_and_psnr_holds() -> None:
    """4 training steps on three 64² pairs (grain on the captures), judged on three others: the record's rows decide
    the keep by the rule, the profile has the stage exactly where kept."""
    camera = CameraProfile(None, [Noise(b=(6.0 / 255) ** 2, linear=False)])
    cleans = [image.float() / 255 for image in dead_leaves_images(6, 64, seed=3)]
    pairs = list(zip(cleans, camera.simulate(cleans, 5, eight_bit=True), strict=True))
    profile, record = run_step(LearnedTexturePaired(steps=4, critic_seeds=1), CameraProfile(None), pairs[:3], pairs[3:])
    rule = (
        record["with"]["critic"] < record["without"]["critic"]
        and record["without"]["psnr"] - record["with"]["psnr"] <= MAX_PSNR_LOSS_DB
    )
    assert record["kept"] is rule and record["steps"] == 4
    assert any(isinstance(effect, LearnedTexture) for effect in profile.effects) is rule
