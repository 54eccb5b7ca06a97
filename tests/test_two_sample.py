"""The two-sample fit of a learned texture stage (issue 43): seeded, resumable to the same bytes, refusing what it
cannot use, and learning a texture the captures have and the named stages do not."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch
from torch import Tensor

from camdegrade import CameraProfile
from camdegrade.effects import LearnedTexture, Noise
from camdegrade.effects.codec.learned_texture import layer_shapes
from camdegrade.errors import CamdegradeError
from camdegrade.fitting import FitInterrupted
from camdegrade.fitting.two_sample.critic import low_pass
from camdegrade.fitting.two_sample.gate import judge_learned_stage, statistics_distance
from camdegrade.fitting.two_sample.train import TwoSampleOptions, _Sampler, fit_two_sample
from effects_images import grainy, smooth_scenes

SMALL = TwoSampleOptions(patch=32, batch=4, width=4, critic_width=4)


def _identity(images) -> list[Tensor]:
    return [image.clone() for image in images]


def _fit(steps: int = 6, **keywords) -> tuple[LearnedTexture, dict]:
    cleans, captures = smooth_scenes(3, 0), grainy(smooth_scenes(3, 1), 8.0, 2)
    return fit_two_sample(_identity, cleans, captures, seed=0, steps=steps, options=SMALL, **keywords)


def test_same_seed_same_bytes_and_a_record_of_the_training() -> None:
    first, evidence = _fit()
    again, _ = _fit()
    assert all(torch.equal(a, b) for a, b in zip(first.state_dict().values(), again.state_dict().values(), strict=True))
    assert first.width == 4 and first.noise and first.magnitude() > 0  # it moved off the identity
    assert evidence["steps"] == 6 and evidence["options"]["patch"] == 32 and evidence["resumed_at"] is None
    first.check_values()


def test_an_interrupted_fit_resumes_to_the_same_bytes(tmp_path: Path) -> None:
    whole, _ = _fit(steps=8)
    path = tmp_path / "state.safetensors"

    def interrupt(step: int, losses: dict) -> None:
        if step == 6:
            raise KeyboardInterrupt

    with pytest.raises(FitInterrupted, match=r"interrupted at step 6 of 8; resume with the same checkpoint"):
        _fit(steps=8, checkpoint=path, checkpoint_every=4, callback=interrupt)
    resumed, evidence = _fit(steps=8, checkpoint=path, checkpoint_every=4, resume=True)
    assert evidence["resumed_at"] == 4
    pairs = zip(whole.state_dict().values(), resumed.state_dict().values(), strict=True)
    assert all(torch.equal(a, b) for a, b in pairs)
    assert path.read_bytes()[:8] and b"pickle" not in path.read_bytes()[:4096]


def test_resume_refuses_other_options_other_data_and_other_files(tmp_path: Path) -> None:
    path = tmp_path / "state.safetensors"
    _fit(steps=4, checkpoint=path, checkpoint_every=4)
    cleans, captures = smooth_scenes(3, 0), grainy(smooth_scenes(3, 1), 8.0, 2)
    other = TwoSampleOptions(patch=32, batch=4, width=4, critic_width=4, content_weight=5.0)
    with pytest.raises(ValueError, match=r"was written with other options .*content_weight"):
        fit_two_sample(_identity, cleans, captures, steps=4, options=other, checkpoint=path, resume=True)
    with pytest.raises(ValueError, match="was written with other data"):
        fit_two_sample(_identity, cleans, captures[:2], steps=4, options=SMALL, checkpoint=path, resume=True)
    with pytest.raises(ValueError, match="resume=True needs checkpoint=PATH"):
        fit_two_sample(_identity, cleans, captures, steps=4, options=SMALL, resume=True)
    profile = CameraProfile(None, [LearnedTexture(4)]).save(tmp_path / "profile.safetensors")
    with pytest.raises(CamdegradeError, match="is not a two-sample checkpoint"):
        fit_two_sample(_identity, cleans, captures, steps=4, options=SMALL, checkpoint=profile, resume=True)


def test_images_too_small_for_a_patch_and_unaligned_pairs_are_refused() -> None:
    cleans = smooth_scenes(2, 0)
    with pytest.raises(ValueError, match="captures must be non-empty images of at least 32x32 pixels"):
        fit_two_sample(_identity, cleans, [torch.rand(3, 16, 64)], steps=1, options=SMALL)
    with pytest.raises(ValueError, match="paired: captures must be aligned with cleans"):
        fit_two_sample(_identity, cleans, smooth_scenes(3, 1), steps=1, options=SMALL, paired=True)
    with pytest.raises(ValueError, match=r"named must give one image per clean image \(2\), got 1"):
        fit_two_sample(lambda images: images[:1], cleans, smooth_scenes(2, 1), steps=1, options=SMALL)


def test_paired_patches_come_from_the_same_place() -> None:
    inputs = smooth_scenes(3, 0)
    sampler = _Sampler(inputs, [image.flip(-1) for image in inputs], 32, 4, paired=True)
    _, reals, noise = sampler.draw(torch.Generator().manual_seed(0))
    places = sampler._crops(inputs, torch.Generator().manual_seed(0))[1]
    flipped = torch.stack([inputs[i].flip(-1)[:, y : y + 32, x : x + 32] for i, y, x in places])
    assert torch.equal(reals, flipped) and noise.shape == (4, 1, 32, 32)


def test_statistics_distance_is_the_rms_of_bands_and_log_noise() -> None:
    assert statistics_distance({"bands": [0.0] * 5, "noise_ratio": 1.0}) == 0.0
    assert statistics_distance({"bands": [0.3] * 5, "noise_ratio": 2.0}) == pytest.approx(math.sqrt((5 * 0.09 + 1) / 6))
    assert statistics_distance({"bands": [0.4, -0.4], "noise_ratio": None}) == pytest.approx(0.4)


@pytest.mark.slow
def test_it_learns_grain_the_captures_have_and_keeps_the_low_frequencies() -> None:
    """Clean scenes through an identity 'profile' against other scenes with 8 levels of white grain: the stage
    adds grain (flat-pixel std from 0 to within a factor 2 of 8 levels) and keeps each image's low-pass."""
    cleans, captures = smooth_scenes(6, 0, side=96), grainy(smooth_scenes(6, 1, side=96), 8.0, 2)
    options = TwoSampleOptions(patch=48, batch=8, width=8, critic_width=8)
    stage, evidence = fit_two_sample(_identity, cleans, captures, seed=0, steps=300, options=options)
    out = stage(torch.stack(cleans), stage.make_params((6, 3, 96, 96), torch.Generator().manual_seed(0)))
    grain = (out - low_pass(out, 2.0)).std().item() * 255
    assert 4.0 <= grain <= 16.0, grain
    drift = (low_pass(out, 2.0) - low_pass(torch.stack(cleans), 2.0)).abs().mean().item() * 255
    assert drift < 2.0, drift
    assert len(evidence["history"]) == 300 // 25


def _grain_stage(levels: float) -> LearnedTexture:
    """A stage whose residual is its noise plane times ``levels`` (8-bit levels) in every channel: the plane passes
    the centre taps as leaky(z) and leaky(−z), whose difference is 1.2·z."""
    weights = {key: torch.zeros(shape) for key, shape in layer_shapes(2).items()}
    weights["conv1_weight"][0, 3, 1, 1], weights["conv1_weight"][1, 3, 1, 1] = 1.0, -1.0
    weights["conv2_weight"][0, 0, 1, 1], weights["conv2_weight"][1, 1, 1, 1] = 1.0, 1.0
    weights["conv3_weight"][:, 0, 1, 1], weights["conv3_weight"][:, 1, 1, 1] = 1.0, -1.0
    weights["conv3_weight"] *= levels / 255 / 1.2
    return LearnedTexture(2, weights=weights)


@pytest.mark.slow
def test_the_gate_keeps_grain_the_captures_have_and_refuses_far_too_much() -> None:
    """Held-out scenes against captures of other scenes with 6 levels of grain: after a profile without grain a
    stage adding 6 levels moves the statistics closer and the fresh critic finds it no easier; after a profile that
    already adds the 6 levels, a stage adding 40 more is refused."""
    cleans, captures = smooth_scenes(6, 3, side=192), grainy(smooth_scenes(6, 4, side=192), 6.0, 5)
    right = judge_learned_stage(CameraProfile(None, []), _grain_stage(6.0), cleans, captures, critic_seeds=1)
    assert right.keep and right.with_stage["distance"] < right.without["distance"], right.to_dict()
    grain_profile = CameraProfile(None, [Noise(b=(6.0 / 255) ** 2, linear=False)])
    wrong = judge_learned_stage(grain_profile, _grain_stage(40.0), cleans, captures, critic_seeds=1)
    assert not wrong.not_farther and not wrong.keep, wrong.to_dict()
    assert wrong.with_stage["noise_ratio"] > 3 * wrong.without["noise_ratio"]
