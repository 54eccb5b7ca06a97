"""The learned texture stage as the unpaired fit's last step (issue 43): asked for by name, fitted after the named
stages and kept only by the held-out halves' judgement, whose statistics rule is the named stages' own (a change
counts only beyond SIGNIFICANCE split-half standard errors)."""

from __future__ import annotations

import pytest
import torch

from camdegrade import CameraProfile
from camdegrade.effects import Noise
from camdegrade.fitting.two_sample.gate import Judgement, LearnedTextureMatch
from camdegrade.fitting.unpaired import fit as unpaired_fit
from camdegrade.fitting.unpaired import fit_unpaired
from camdegrade.fitting.unpaired.fit import UNPAIRED_EFFECTS, UNPAIRED_OPTIONAL, check_unpaired_effects
from camdegrade.fitting.unpaired.judges import SIGNIFICANCE
from camdegrade.synthetic import dead_leaves_images

torch.set_num_threads(1)


def _row(distance: float, critic: float) -> dict:
    return {"distance": distance, "critic": critic}


@pytest.mark.parametrize(
    ("change", "error", "critic_after", "keep"),
    [
        (0.03, 0.02, 0.64, True),  # farther by 1.5 standard errors: within what the images' content moves it
        (0.03, 0.005, 0.64, False),  # the same change 6 standard errors out: farther
        (-0.05, 0.02, 0.64, True),  # closer
        (-0.05, 0.02, 0.74, False),  # closer, but the fresh critic does not fall
        (-0.05, 0.02, 0.73, False),  # nor when it stays where it was
    ],
)
def test_the_gate_holds_statistics_to_their_split_half_error_and_wants_the_critic_to_fall(
    change: float, error: float, critic_after: float, keep: bool
) -> None:
    judgement = Judgement(without=_row(0.30, 0.73), with_stage=_row(0.30 + change, critic_after), change_error=error)
    assert judgement.keep is keep
    assert judgement.closer is (change <= SIGNIFICANCE * error)
    assert judgement.to_dict()["keep"] is keep


def test_the_learned_stage_is_fitted_only_when_asked_for() -> None:
    assert "learned_texture" in UNPAIRED_OPTIONAL and "learned_texture" not in UNPAIRED_EFFECTS
    assert check_unpaired_effects(["noise", "learned_texture"]) == ["noise", "learned_texture"]
    with pytest.raises(ValueError, match=r"effects must be names from .*'learned_texture'.*got 'texture'"):
        check_unpaired_effects(["texture"])


@pytest.mark.slow
def test_the_step_runs_last_trains_after_the_named_stages_and_records_its_judgement(monkeypatch) -> None:
    """A tiny fit (16 grainy captures of 96², 16 clean images, 4 training steps): the step's record holds both
    halves' judgements (or the first, refused) and a training per half plus one on all where kept; the profile
    has the stage last exactly where the record says kept, and the same seed gives the same profile."""
    steps = tuple(
        (label, LearnedTextureMatch(steps=4) if isinstance(step, LearnedTextureMatch) else step)
        for label, step in unpaired_fit.UNPAIRED_STEPS
    )
    assert isinstance(steps[-1][1], LearnedTextureMatch)
    monkeypatch.setattr(unpaired_fit, "UNPAIRED_STEPS", steps)
    camera = CameraProfile(None, [Noise(b=(5.0 / 255) ** 2, linear=False)])
    captures = camera.simulate([image.float() / 255 for image in dead_leaves_images(16, 96, seed=2)], 7, eight_bit=True)
    cleans = list(dead_leaves_images(16, 96, seed=1))
    profiles = [fit_unpaired(captures, cleans, effects=("learned_texture",)) for _ in range(2)]
    record = profiles[0].fitted["effects"]["learned_texture"]
    kept = record["kept"]
    assert len(record["judgements"]) == (2 if record["judgements"][0]["keep"] else 1)
    assert kept == all(judgement["keep"] for judgement in record["judgements"]) and len(record["judgements"]) >= 1
    assert len(record["training_seconds"]) == len(record["judgements"]) + (1 if kept else 0)
    assert profiles[0].effect_names == (["learned_texture"] if kept else [])
    first, again = (
        {key: value for effect in p.effects for key, value in effect.state_dict().items()} for p in profiles
    )
    assert first.keys() == again.keys() and all(torch.equal(first[key], again[key]) for key in first)
