"""The learned texture stage (issue 43): identity at the start, seeded replay through a profile file, its
deterministic centre, frames processed in strips, and refusals naming what is wrong."""

from __future__ import annotations

import pytest
import torch

from camdegrade import CameraProfile, load_profile
from camdegrade.effects import EFFECTS, Blur, LearnedTexture
from camdegrade.effects.codec.learned_texture import STRIP_ROWS, layer_shapes
from camdegrade.functional.optics.blur import blur_image
from effects_images import photo_batch
from test_effects import strong


def test_a_new_stage_is_the_identity_and_training_starts_there() -> None:
    image = photo_batch()
    for stage in (LearnedTexture(), LearnedTexture.initial(8, seed=3)):
        params = stage.make_params(image.shape, torch.Generator().manual_seed(0))
        assert torch.equal(stage(image, params), image)
    assert LearnedTexture.initial(8, seed=3).conv1_weight.abs().sum() > 0  # hidden layers drawn, output zero
    assert sum(v.numel() for v in LearnedTexture().state_dict().values()) == 1099  # width 8
    assert sum(v.numel() for v in LearnedTexture(12).state_dict().values()) == 2079


def test_same_seed_same_bytes_through_a_saved_profile(tmp_path) -> None:
    profile = CameraProfile(None, [Blur(0.8), strong("learned_texture")], name="learned")
    loaded = load_profile(profile.save(tmp_path / "learned.safetensors"))
    image = photo_batch()
    first = profile(image, profile.make_params(image.shape, torch.Generator().manual_seed(4)))
    again = loaded(image, loaded.make_params(image.shape, torch.Generator().manual_seed(4)))
    other = loaded(image, loaded.make_params(image.shape, torch.Generator().manual_seed(5)))
    assert torch.equal(first, again)
    assert (first - other).abs().max() > 2 / 255  # the noise plane moves the texture
    assert [effect.name for effect in loaded.effects] == ["blur", "learned_texture"]


def test_the_deterministic_centre_is_the_stage_with_its_noise_plane_at_zero() -> None:
    stage = strong("learned_texture")
    centre = stage.without_randomness()
    image = photo_batch()
    assert centre.make_params(image.shape, torch.Generator()) == {} and centre.config()["noise"] is False
    zero = {"noise": torch.zeros(image.shape[0], 1, *image.shape[-2:])}
    assert torch.equal(centre(image, {}), stage(image, zero))
    assert stage.noise  # the original keeps drawing


def test_a_tall_frame_is_computed_in_strips_equal_to_one_pass() -> None:
    stage = strong("learned_texture")
    image = torch.rand(1, 3, STRIP_ROWS * 2 + 37, 40, generator=torch.Generator().manual_seed(0))
    params = stage.make_params(image.shape, torch.Generator().manual_seed(1))
    with torch.no_grad():
        strips = stage(image, params)
    whole = stage(image.clone().requires_grad_(), params).detach()  # with a graph: one pass
    torch.testing.assert_close(strips, whole, atol=1e-6, rtol=0)


def test_it_changes_texture_not_the_low_frequencies() -> None:
    """The residual's own low-pass is taken out: colour and shading stay the named stages'."""
    stage = strong("learned_texture")
    image = photo_batch(64, 96)
    out = stage(image, stage.make_params(image.shape, torch.Generator().manual_seed(0)))
    unprojected = LearnedTexture(8, sigma=0.0, weights=dict(stage.named_buffers()))
    raw = unprojected(image, unprojected.make_params(image.shape, torch.Generator().manual_seed(0)))
    inner = (..., slice(8, -8), slice(8, -8))  # away from the borders, whose padding differs
    low = (blur_image(out, 3.0) - blur_image(image, 3.0))[inner].abs().mean() * 255
    raw_low = (blur_image(raw, 3.0) - blur_image(image, 3.0))[inner].abs().mean() * 255
    assert (out - image).abs().mean() * 255 > 1.0 and low < 0.25 < raw_low, (low, raw_low)


def test_scaled_scales_the_residual() -> None:
    stage = strong("learned_texture")
    image = photo_batch()
    params = stage.make_params(image.shape, torch.Generator().manual_seed(0))
    out = stage(image, params)
    full, half = out - image, stage.scaled(0.5)(image, params) - image
    unclipped = (out > 0) & (out < 1)
    torch.testing.assert_close(half[unclipped], 0.5 * full[unclipped], atol=1e-6, rtol=0)
    assert stage.scaled(2.0).magnitude() == pytest.approx(2 * stage.magnitude())


def test_it_is_no_diagnosis_candidate_and_has_no_pair_fitter() -> None:
    assert EFFECTS["learned_texture"] is LearnedTexture and LearnedTexture.candidate is False
    with pytest.raises(NotImplementedError, match="has no fitter"):
        LearnedTexture.fit(photo_batch(), photo_batch())


@pytest.mark.parametrize(
    ("arguments", "error", "message"),
    [
        ({"width": 0}, ValueError, "width must be an integer from 1 to 64, got width=0"),
        ({"width": 8.0}, ValueError, "width must be an integer from 1 to 64, got width=8.0"),
        ({"noise": "yes"}, TypeError, "noise must be True or False, got noise='yes'"),
        ({"sigma": 9.0}, ValueError, "sigma must be from 0 to 8, got sigma=9"),
        ({"sigma": "1"}, TypeError, "sigma must be a number, got sigma='1'"),
        ({"width": 4, "weights": {}}, ValueError, r"weights must hold every buffer: missing \['conv1_bias'"),
        (
            {"width": 4, "weights": {**{k: torch.zeros(s) for k, s in layer_shapes(4).items()}, "x": torch.zeros(1)}},
            ValueError,
            r"missing \[\], unexpected \['x'\]",
        ),
        (
            {"width": 4, "weights": {k: torch.zeros(s[::-1]) for k, s in layer_shapes(4).items()}},
            ValueError,
            r"conv1_weight must have shape \(4, 4, 3, 3\), got shape \(3, 3, 4, 4\)",
        ),
        (
            {"width": 4, "weights": {k: torch.full(s, 100.0) for k, s in layer_shapes(4).items()}},
            ValueError,
            "conv1_weight must be from -64 to 64, got conv1_weight=",
        ),
    ],
)
def test_bad_arguments_are_named(arguments: dict, error: type, message: str) -> None:
    with pytest.raises(error, match=message):
        LearnedTexture(**arguments)


def test_a_weight_out_of_range_is_refused_at_save(tmp_path) -> None:
    stage = strong("learned_texture")
    stage.conv2_weight[0, 0, 0, 0] = 1e3
    with pytest.raises(ValueError, match=r"learned_texture\): conv2_weight must be from -64 to 64"):
        CameraProfile(None, [stage]).save(tmp_path / "bad.safetensors")
    assert not (tmp_path / "bad.safetensors").exists()


def test_the_diagnosis_may_remove_a_learned_stage_but_never_refits_it() -> None:
    """A refit calls the stage's pair fitter, which a learned stage lacks: it used to end the diagnosis with a
    NotImplementedError."""
    from camdegrade.diagnose.attribution.changes import RefitStage, RemoveStage

    profile = CameraProfile(None, [Blur(0.8), strong("learned_texture")])
    assert [plan.target for plan in RefitStage().plans(profile, [], {"frequency"})] == [0]
    assert [plan.target for plan in RemoveStage().plans(profile, [], {"frequency"})] == [0, 1]
    assert Blur.has_pair_fitter() and not LearnedTexture.has_pair_fitter()
