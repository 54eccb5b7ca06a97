"""A fit's noise-reduction stage (:mod:`camdegrade.fitting.steps.denoise`): kept where the camera cores its output."""

from __future__ import annotations

import pytest
import torch

from camdegrade import CameraProfile
from camdegrade.effects import Blur, Denoise, Sharpen
from camdegrade.fitting import FitConfig, fit_profile
from camdegrade.fitting.steps.denoise import DenoiseMatch
from camdegrade.functional.isp.sharpen import denoise_image, denoised_with_detail, image_detail
from camdegrade.synthetic import dead_leaves_images
from steps_for_tests import run_step

torch.set_num_threads(1)


def _grainy(count: int, seed: int) -> list[torch.Tensor]:
    """Dead-leaves textures in [0.2, 0.8] with faint fine grain (1.5 levels), the detail a camera's coring removes."""
    generator = torch.Generator().manual_seed(seed)
    return [
        0.2 + 0.6 * image.float() / 255 + 1.5 / 255 * torch.randn(1, 96, 96, generator=generator)
        for image in dead_leaves_images(count, 96, seed=seed)
    ]


def _pairs(images: list[torch.Tensor], *stages) -> list[tuple[torch.Tensor, torch.Tensor]]:
    camera = CameraProfile(None, list(stages))
    with torch.no_grad():
        return [(image, camera(image[None])[0]) for image in images]


def test_a_camera_that_cores_gets_a_denoise_stage_after_its_other_stages() -> None:
    notes: list[str] = []
    base = CameraProfile(None, [Sharpen(1.0, 0.5)])
    camera = [Sharpen(1.0, 0.5), Denoise(1.0, 4 / 255)]
    profile, note = run_step(
        DenoiseMatch(), base, _pairs(_grainy(6, 0), *camera), _pairs(_grainy(4, 1), *camera), notes.append
    )
    assert note["kept"] and abs(note["threshold_levels"] - 4.0) < 1.0 and abs(note["sigma"] - 1.0) < 0.25, note
    assert note["val_psnr_after"] - note["val_psnr_before"] > 1.0, note
    assert [type(effect) for effect in profile.effects] == [Sharpen, Denoise]
    assert notes and notes[0].startswith("denoise: sigma") and "-> kept" in notes[0]


def test_a_camera_that_keeps_its_faint_detail_gets_none() -> None:
    camera = Blur(0.6, linear=False)
    base = CameraProfile(None, [Blur(0.6, linear=False)])
    profile, note = run_step(
        DenoiseMatch(), base, _pairs(_grainy(6, 2), camera), _pairs(_grainy(4, 3), camera), lambda _: None
    )
    assert not note["kept"] and len(profile.effects) == 1, note


def test_a_profile_with_a_denoise_stage_is_left_alone() -> None:
    base = CameraProfile(None, [Denoise(1.0, 0.01)])
    pairs = _pairs(_grainy(2, 4), Denoise(1.0, 0.01))
    profile, note = run_step(DenoiseMatch(), base, pairs, pairs, lambda _: None)
    assert note == {"kept": False, "reason": "the profile already has a denoise stage"} and profile is base


@pytest.mark.slow
def test_a_fit_records_its_denoise_step_and_the_paper_recipe_skips_it() -> None:
    pairs = [
        ((clean * 255).round().to(torch.uint8), (captured * 255).round().to(torch.uint8))
        for clean, captured in _pairs([image.clamp(0, 1) for image in _grainy(10, 5)], Denoise(1.0, 6 / 255))
    ]
    quick = FitConfig(epochs=1, crop=32, crops_per_pair=2, width=4, val_fraction=0.3).replace(effects=())
    matched = fit_profile(pairs, quick).fitted["denoise"]
    assert set(matched) >= {"kept", "sigma", "threshold_levels", "val_psnr_before", "val_psnr_after"}, matched
    skipped = fit_profile(pairs, quick.replace(texture="none")).fitted["denoise"]
    assert skipped == {"kept": False, "reason": "texture='none'"}


def test_a_detail_taken_once_denoises_as_the_kernel_does_at_every_threshold() -> None:
    """The step tries every threshold of a sigma on one detail (:func:`image_detail`): the kernel's very values."""
    images = [torch.rand(3, 37, 52, generator=torch.Generator().manual_seed(seed)) for seed in range(2)]
    for image in images:
        for sigma in (0.7, 1.5):
            detail = image_detail(image, sigma)
            for level in (1.0, 4.0):
                expected = denoise_image(image, sigma, level / 255)
                assert torch.equal(denoised_with_detail(image, detail, level / 255), expected)
