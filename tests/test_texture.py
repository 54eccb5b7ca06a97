"""The texture step of a fit (:mod:`camdegrade.fitting.steps.texture`): a blur and a sharpening chosen by band
power."""

from __future__ import annotations

import pytest
import torch

from camdegrade import CameraProfile
from camdegrade.effects import Blur, Noise, Sharpen
from camdegrade.fitting import FitConfig, fit_profile
from camdegrade.fitting.steps.texture import TextureMatch, _bin_centres, band_errors, radial_powers, transfer
from camdegrade.measures.fidelity import band_log2_ratios
from camdegrade.synthetic import dead_leaves_images
from steps_for_tests import run_step

torch.set_num_threads(1)


def _images(count: int, seed: int) -> list[torch.Tensor]:
    """Dead-leaves textures squeezed to [0.2, 0.8], so that no stage clips."""
    return [0.2 + 0.6 * image.float() / 255 for image in dead_leaves_images(count, 128, seed=seed)]


def _camera(images: list[torch.Tensor], *stages) -> list[tuple[torch.Tensor, torch.Tensor]]:
    camera = CameraProfile(None, list(stages))
    with torch.no_grad():
        return [
            (image, camera(image[None], camera.make_params((1, *image.shape), torch.Generator().manual_seed(i)))[0])
            for i, image in enumerate(images)
        ]


def test_the_radial_bins_give_the_fidelity_bands() -> None:
    images = _images(3, seed=0)
    softened = [Blur(0.8, linear=False)(image[None])[0] for image in images]
    pooled = band_errors(radial_powers(softened), radial_powers(images))
    measured = band_log2_ratios(torch.stack(softened), torch.stack(images))
    assert torch.allclose(pooled, torch.tensor(measured, dtype=pooled.dtype), atol=0.02), (pooled, measured)


@pytest.mark.parametrize(("blur", "sigma", "amount"), [(0.6, 1.5, 0.0), (0.0, 1.0, 1.0), (0.7, 0.7, 2.0)])
def test_the_predicted_band_power_is_what_the_stages_do(blur: float, sigma: float, amount: float) -> None:
    """The transfer functions predict the stages' band power within 0.05 log2 in every band."""
    images = _images(3, seed=1)
    stages = CameraProfile(None, [*([Blur(blur, linear=False)] if blur else []), Sharpen(sigma, amount)])
    with torch.no_grad():
        done = [stages(image[None])[0] for image in images]
    gain_blur, gain_both = transfer(blur, sigma, amount, _bin_centres())
    predicted = radial_powers(images) * gain_both.pow(2) * gain_blur.pow(2)
    error = band_errors(predicted, radial_powers(done))
    assert float(error.abs().max()) < 0.05, error


def test_a_camera_softer_than_the_profile_gets_a_blur_that_matches_its_bands() -> None:
    pairs = _camera(_images(8, seed=2), Blur(1.0, linear=False))
    held = _camera(_images(6, seed=3), Blur(1.0, linear=False))
    notes: list[str] = []
    profile, note = run_step(TextureMatch(), CameraProfile(None), pairs, held, notes.append)
    assert note["kept"] is True, note
    assert 0.7 <= note["blur_sigma"] <= 1.2 and note["val_error_after"] < 0.15 < note["val_error_before"], note
    assert [effect.name for effect in profile.effects] == ["blur", "sharpen"][: len(profile.effects)]
    assert notes and notes[0].startswith("texture: blur sigma") and "-> kept" in notes[0]


def test_a_camera_sharper_than_the_profile_gets_a_sharpening() -> None:
    pairs = _camera(_images(8, seed=4), Sharpen(1.0, 1.0))
    held = _camera(_images(6, seed=5), Sharpen(1.0, 1.0))
    profile, note = run_step(TextureMatch(), CameraProfile(None), pairs, held, lambda _: None)
    assert note["kept"] is True and note["sharpen_amount"] >= 0.5, note
    assert any(effect.name == "sharpen" for effect in profile.effects)


def test_a_profile_that_already_matches_gets_no_texture_stage() -> None:
    """The control: captures with the profile's own noise and nothing else; any choice is dropped on validation."""
    noise = Noise(a=0.0004, b=1e-5)
    pairs = _camera(_images(8, seed=6), noise)
    held = _camera(_images(6, seed=7), noise)
    profile, note = run_step(TextureMatch(), CameraProfile(None, [noise]), pairs, held, lambda _: None)
    assert note["kept"] is False, note
    assert [effect.name for effect in profile.effects] == ["noise"]


def test_a_profile_with_its_own_blur_is_left_alone() -> None:
    pairs = _camera(_images(2, seed=8), Blur(1.0, linear=False))
    profile = CameraProfile(None, [Blur(0.5)])
    kept, note = run_step(TextureMatch(), profile, pairs, pairs, lambda _: None)
    assert kept is profile and note == {"kept": False, "reason": "the profile already has a blur or sharpen stage"}


def test_the_recipes_choose_the_texture_step() -> None:
    assert (FitConfig.recipe("fast").option("texture"), FitConfig.recipe("paper").option("texture")) == (
        "match",
        "none",
    )
    with pytest.raises(ValueError, match=r"texture must be one of \('match', 'none'\), got texture='sharp'"):
        FitConfig().replace(texture="sharp")
    assert "texture" not in FitConfig().training_dict()


@pytest.mark.slow
def test_a_fit_records_its_texture_step_and_the_paper_recipe_skips_it() -> None:
    images = [(image * 255).round().to(torch.uint8) for image in _images(10, seed=9)]
    pairs = [
        (clean, (captured * 255).round().to(torch.uint8))
        for clean, captured in _camera([image.float() / 255 for image in images], Blur(1.2, linear=False))
    ]
    quick = FitConfig(epochs=1, crop=32, crops_per_pair=2, width=4, val_fraction=0.3).replace(effects=())
    matched = fit_profile(pairs, quick).fitted["texture"]
    assert set(matched) >= {"blur_sigma", "sharpen_sigma", "sharpen_amount", "kept", "val_error_before"}, matched
    skipped = fit_profile(pairs, quick.replace(texture="none")).fitted["texture"]
    assert skipped == {"kept": False, "reason": "texture='none'"}
