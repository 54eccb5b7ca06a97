"""The edge spread of strong isolated steps (:mod:`camdegrade.functional.analysis.edges`) and the unpaired fit's use
of it (:mod:`camdegrade.fitting.unpaired.steps.edges`): scenes of flat rectangles, blurred, sharpened, aliased and
compressed by PIL and numpy (not camdegrade's kernels)."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest
import torch
from PIL import Image, ImageFilter

from camdegrade.fitting.unpaired import fit_unpaired
from camdegrade.fitting.unpaired.steps.edges import EdgeSpread, blur_by_edges, farther, sharpens_away
from camdegrade.functional.analysis.edges import median_step_width, step_widths
from camdegrade.synthetic import dead_leaves_images

SIDE = 160


def _rectangles(seed: int, count: int = 6, side: int = SIDE) -> list[Image.Image]:
    """Scenes of 14 overlapping flat grey-level rectangles each (long, isolated, axis-aligned steps), 8-bit RGB."""
    rng = np.random.default_rng(seed)
    scenes = []
    for _ in range(count):
        image = np.full((side, side, 3), rng.integers(30, 220), dtype=np.uint8)
        for _ in range(14):
            top, left = rng.integers(0, side - 24, 2)
            height, width = rng.integers(20, side // 2, 2)
            image[top : top + height, left : left + width] = rng.integers(0, 256, 3)
        scenes.append(Image.fromarray(image))
    return scenes


def _tensor(image: Image.Image) -> torch.Tensor:
    return torch.from_numpy(np.array(image.convert("RGB"))).permute(2, 0, 1).contiguous()


def _blurred(sigma: float, seed: int = 0) -> list[torch.Tensor]:
    return [_tensor(scene.filter(ImageFilter.GaussianBlur(sigma))) for scene in _rectangles(seed)]


def test_the_width_grows_as_a_gaussian_blur_s_rise_does() -> None:
    widths = [median_step_width(_blurred(sigma))[0] for sigma in (1.0, 1.5, 2.0)]
    # a Gaussian edge rises from 10 % to 90 % over 2.56 sigma; PIL's box approximation and the pixels add a little
    for sigma, width in zip((1.0, 1.5, 2.0), widths, strict=True):
        assert abs(width - 2.56 * sigma) <= 0.35, widths
    assert widths[0] < widths[1] < widths[2]


def test_noise_hardly_moves_it_and_sharpening_narrows_it() -> None:
    images = _blurred(1.5)
    clean, steps = median_step_width(images)
    rng = np.random.default_rng(3)
    noisy = [
        torch.from_numpy(np.clip(image.numpy() + rng.normal(0, 6, image.shape), 0, 255).round().astype(np.uint8))
        for image in images
    ]
    assert steps >= 500
    assert abs(median_step_width(noisy)[0] - clean) <= 0.1
    sharpened = [
        _tensor(scene.filter(ImageFilter.GaussianBlur(1.5)).filter(ImageFilter.UnsharpMask(2, 100, 0)))
        for scene in _rectangles(0)
    ]
    assert median_step_width(sharpened)[0] < clean - 0.5


def test_an_image_without_steps_has_no_width_and_a_wrong_shape_is_named() -> None:
    assert len(step_widths(torch.full((3, 64, 64), 0.5))) == 0
    assert np.isnan(median_step_width([torch.full((3, 64, 64), 0.5)])[0])
    with pytest.raises(ValueError, match=r"image must be a \(3, H, W\) RGB tensor, got shape \(64, 64\)"):
        step_widths(torch.zeros(64, 64))


def test_the_blur_is_read_between_the_sigmas_that_bracket_the_captures_width() -> None:
    assert blur_by_edges({1.0: 2.6, 1.5: 3.8, 2.0: 5.0}, 3.2) == 1.25
    assert blur_by_edges({1.0: 2.6, 1.5: 3.8}, 9.0) == 1.5
    assert blur_by_edges({1.0: float("nan")}, 3.0) is None


def test_a_stage_is_refused_only_where_it_takes_the_width_away_from_the_captures() -> None:
    spread = EdgeSpread(3.3, 1000, 0.01)  # tolerance 0.25, slack 0.05
    assert sharpens_away(spread, 3.3, 3.1) and not sharpens_away(spread, 3.6, 3.35)
    assert not farther(spread, 3.3, 3.5) and farther(spread, 3.3, 3.6)
    unmeasured = EdgeSpread(float("nan"), 0, float("nan"))
    assert not sharpens_away(unmeasured, 3.3, 2.0) and not farther(unmeasured, 3.3, 2.0)
    assert json.dumps(unmeasured.record(), allow_nan=False) == (
        '{"captures": null, "steps": 0, "tolerance": 0.25, "slack": 0.05}'
    )  # a fit's record is JSON: no NaN


def _aliasing_camera(scene: Image.Image) -> torch.Tensor:
    """PIL's Gaussian blur (1.5 px), a sensor of a third of the pixels read without a prefilter (nearest), a bicubic
    upscale and JPEG at quality 90: top-band power from aliasing and the codec, not from sharp edges."""
    blurred = scene.filter(ImageFilter.GaussianBlur(1.5))
    side = blurred.size[0]
    upscaled = blurred.resize((side // 3, side // 3), Image.NEAREST).resize((side, side), Image.BICUBIC)
    buffer = io.BytesIO()
    upscaled.save(buffer, "JPEG", quality=90)
    buffer.seek(0)
    return _tensor(Image.open(buffer))


@pytest.mark.slow
def test_aliasing_and_codec_texture_are_not_matched_by_sharpening() -> None:
    """Before the edge spread, the spectrum alone chose blur 1.25 px and sharpening 0.5 for this camera: its
    simulation's steps were 3.39 px wide against the captures' 4.44 (now blur 1.5 alone: 4.28). The top bands'
    power, aliasing and the codec's, is left to stages that make texture (none here: −2.7 and −4.4 log2)."""
    scenes = dead_leaves_images(16, 192, seed=2)
    captures = [_aliasing_camera(Image.fromarray(scene.permute(1, 2, 0).numpy())) for scene in scenes]
    clean = dead_leaves_images(16, 192, seed=1)
    profile = fit_unpaired(captures, clean, effects=("blur", "sharpen"))
    kept = [effect.name for effect in profile.effects]
    record = profile.fitted["effects"]["transfer"]
    assert kept == ["blur"], record
    assert record["by_spectrum_alone"][1] > 0, record  # the spectrum alone still asks for sharpening
    simulated = median_step_width(profile.simulate(clean, 0, eight_bit=True))[0]
    assert abs(simulated - median_step_width(captures)[0]) <= 0.25, record
