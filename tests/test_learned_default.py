"""The learned texture stage as the unpaired fit's default (issue 43): run by default where each half of each set holds
enough disjoint training patches, recorded as not fitted with the numbers where it does not, off with
``effects`` (``fit --unpaired --learned-texture none``), in three parts that the progress bar counts and the
checkpoint holds: a fit interrupted after the first part resumes to the bytes of one never interrupted."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
import torch

from camdegrade import CameraProfile
from camdegrade.effects import Noise
from camdegrade.errors import FitInterrupted
from camdegrade.fitting.two_sample import step as step_module
from camdegrade.fitting.two_sample.gate import Judgement, judge_half
from camdegrade.fitting.two_sample.step import (
    MAX_DRAWS_PER_PATCH,
    LearnedTextureMatch,
    needed_patches,
    too_few_patches,
)
from camdegrade.fitting.unpaired import UNPAIRED_EFFECTS, fit_unpaired
from camdegrade.fitting.unpaired import fit as unpaired_fit
from camdegrade.synthetic import dead_leaves_images

torch.set_num_threads(1)


def _strips(*patches: int) -> list[torch.Tensor]:
    """Images of one row of ``n`` disjoint 64² patches each (and 63 pixels more: no further patch)."""
    return [torch.zeros(1).expand(3, 64 + 63, 64 * n + 63) for n in patches]


def test_the_sets_are_enough_where_each_half_of_each_holds_a_tenth_of_a_trainings_draws() -> None:
    need = needed_patches(1200)
    assert need == 1200 * 8 // MAX_DRAWS_PER_PATCH == 960
    enough = _strips(480, 480, 480, 480)  # halves A and B (alternate images): 960 each
    assert too_few_patches(enough, enough, 1200) is None
    short = _strips(480, 480, 480, 479)
    assert too_few_patches(enough, short, 1200) == (
        "too few images for a learned texture stage: half B of the captures holds 959 disjoint 64x64 patches, it "
        "needs 960 (a training draws 9600; with fewer than a 10th as many distinct ones its critic learns those "
        "patches, not the camera)"
    )
    assert "half A of the clean images holds 959" in too_few_patches(short[::-1], enough, 1200)
    assert too_few_patches(short, short, 1190) is None  # a shorter training needs fewer: 952


def _scenes(count: int, size: int, seed: int) -> list[torch.Tensor]:
    """Dead-leaves scenes, 8-bit, each with a flat grey square of half its side (flat pixels for the noise)."""
    scenes = []
    for index, image in enumerate(dead_leaves_images(count, size, seed=seed)):
        image, corner = image.clone(), (index * 7) % (size // 2)
        image[:, corner : corner + size // 2, corner : corner + size // 2] = 60 + 20 * (index % 8)
        scenes.append(image)
    return scenes


def _sides(count: int, size: int) -> tuple[list[torch.Tensor], list[torch.Tensor]]:
    """(grainy captures of scenes, other clean scenes), 8-bit."""
    camera = CameraProfile(None, [Noise(b=(5.0 / 255) ** 2, linear=False)])
    scenes = [image.float() / 255 for image in _scenes(count, size, 2)]
    return camera.simulate(scenes, 7, eight_bit=True), _scenes(count, size, 1)


def test_a_fit_of_too_few_images_records_why_it_has_no_learned_stage(learned_texture) -> None:
    """8 images of 96² a side: 4 patches of 64² a half, 960 needed."""
    captures, cleans = _sides(8, 96)
    profile = fit_unpaired(captures, cleans, effects=("learned_texture",))
    reason = profile.fitted["not_fitted"]["learned_texture"]
    assert reason.startswith("too few images for a learned texture stage: half A of the captures holds 4 disjoint")
    assert profile.fitted["effects"]["learned_texture"] == {"kept": False, "reason": reason, "steps": 1200}
    assert profile.effect_names == []


@pytest.mark.slow
def test_a_default_fit_tries_it_and_one_without_it_does_not(learned_texture) -> None:
    """The same images, every default stage: the learned step records why it fitted nothing; ``effects`` without it
    (``fit --unpaired --learned-texture none``): no record, the same named stages."""
    captures, cleans = _sides(8, 96)
    profile = fit_unpaired(captures, cleans)
    assert profile.fitted["not_fitted"]["learned_texture"].startswith("too few images for a learned texture stage")
    off = fit_unpaired(captures, cleans, effects=UNPAIRED_EFFECTS[:-1])
    assert "learned_texture" not in off.fitted["not_fitted"] and "learned_texture" not in off.fitted["effects"]
    assert off.effect_names == profile.effect_names and "learned_texture" not in profile.effect_names


@pytest.fixture
def short_trainings_kept(monkeypatch: pytest.MonkeyPatch, learned_texture) -> None:
    """The learned parts train 4 steps (so 4 patches of 64² a half are enough), and every judgement keeps its stage
    (its critic with the stage put 0.01 below the one without, its statistics on the captures': 4 steps train no
    stage a judge would keep)."""
    steps = tuple(
        (label, replace(step, steps=4) if isinstance(step, LearnedTextureMatch) else step)
        for label, step in unpaired_fit.UNPAIRED_STEPS
    )
    monkeypatch.setattr(unpaired_fit, "UNPAIRED_STEPS", steps)

    def kept(*args, **options) -> tuple[Judgement, dict]:
        judgement, record = judge_half(*args, **options)
        lower = {**judgement.with_stage, "critic": judgement.without["critic"] - 0.01, "distance": 0.0}
        return Judgement(judgement.without, lower, judgement.change_error), record

    monkeypatch.setattr(step_module, "judge_half", kept)


def _bytes(profile: CameraProfile, path: Path) -> bytes:
    profile.fitted["fit_minutes"] = 0.0
    profile.save(path)
    return path.read_bytes()


@pytest.mark.slow
def test_a_default_fit_runs_it_and_resumes_after_its_first_part_to_the_same_bytes(
    short_trainings_kept, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """8 grainy captures of 96², every default stage: the learned step runs in its three parts, the stage kept;
    interrupted in its second part (step 17 of 18), resumed, it gives the uninterrupted fit's bytes without
    training half A again."""
    captures, cleans = _sides(8, 96)
    whole = fit_unpaired(captures, cleans)
    record = whole.fitted["effects"]["learned_texture"]
    assert record["kept"] and len(record["judgements"]) == 2 and record["trainings"] == 3, record
    assert whole.effect_names[-1] == "learned_texture"
    calls: list[str] = []
    original = LearnedTextureMatch.propose

    def stop_in_half_b(self, fit):
        calls.append(self.part)
        if self.part == "half B" and calls.count("half B") == 1:
            raise KeyboardInterrupt
        return original(self, fit)

    monkeypatch.setattr(LearnedTextureMatch, "propose", stop_in_half_b)
    checkpoint = tmp_path / "fit.ckpt.safetensors"
    with pytest.raises(FitInterrupted, match=r"during step 17 of 18 \(learned texture: trained on half B, judged"):
        fit_unpaired(captures, cleans, checkpoint=checkpoint)
    resumed = fit_unpaired(captures, cleans, checkpoint=checkpoint, resume=True)
    assert calls == ["half A", "half B", "half B", "all"]
    assert _bytes(resumed, tmp_path / "resumed.safetensors") == _bytes(whole, tmp_path / "whole.safetensors")
