"""The thin-line width (:func:`camdegrade.functional.analysis.edges.line_widths`), the area-sampling sensor
(:func:`camdegrade.functional.sensor.resolution.resolution_image` with ``sample="area"``) and the unpaired fit's
area-sensor step (:mod:`camdegrade.fitting.unpaired.steps.area_sensor`), on cameras made with PIL, numpy and scipy,
not camdegrade's kernels: a sensor of 0.4 the pixels (PIL's box reduction), PIL's bicubic upscale, PIL's unsharp mask
and JPEG, where the step must find the sensor; a Gaussian blur in linear light and JPEG, where it must keep none."""

from __future__ import annotations

import io
import math

import numpy as np
import pytest
import torch
from PIL import Image, ImageFilter
from scipy.ndimage import gaussian_filter

from camdegrade.effects import Blur, Resolution, Sharpen
from camdegrade.fitting.unpaired import fit_unpaired
from camdegrade.fitting.unpaired.bench import AREA_ORDER
from camdegrade.fitting.unpaired.fit import UNPAIRED_STEPS
from camdegrade.fitting.unpaired.sensor import check_area_sensor, with_sensor
from camdegrade.fitting.unpaired.steps.area_sensor import (
    MIN_COUNT,
    AreaSensorMatch,
    SetWidths,
    descend,
    distance,
    set_widths,
)
from camdegrade.functional.analysis.edges import line_widths
from camdegrade.functional.sensor.resolution import resolution_image

SIDE = 192


def _strokes(seed: int, count: int = 16, side: int = SIDE) -> list[Image.Image]:
    """Scenes of 10 flat rectangles (steps) and 24 one-pixel lines (strokes), axis-aligned, 8-bit RGB."""
    rng = np.random.default_rng(seed)
    scenes = []
    for _ in range(count):
        image = np.full((side, side, 3), rng.integers(40, 216), dtype=np.uint8)
        for _ in range(10):
            top, left = rng.integers(0, side - 24, 2)
            height, width = rng.integers(16, side // 2, 2)
            image[top : top + height, left : left + width] = rng.integers(0, 256, 3)
        for _ in range(24):
            top, left = rng.integers(8, side - 8, 2)
            length, value = rng.integers(16, 80), rng.integers(0, 256, 3)
            if rng.random() < 0.5:
                image[top, left : left + length] = value
            else:
                image[top : top + length, left] = value
        scenes.append(Image.fromarray(image))
    return scenes


def _tensor(image: Image.Image) -> torch.Tensor:
    return torch.from_numpy(np.array(image.convert("RGB"))).permute(2, 0, 1).contiguous()


def _jpeg(image: Image.Image, quality: int = 90) -> torch.Tensor:
    buffer = io.BytesIO()
    image.save(buffer, "JPEG", quality=quality)
    buffer.seek(0)
    return _tensor(Image.open(buffer))


def _sensor_camera(scene: Image.Image) -> torch.Tensor:
    """A sensor of 0.4 the pixels each side read by area (PIL's box reduction), PIL's bicubic upscale, PIL's unsharp
    mask (radius 2, 80 %) and JPEG 90."""
    side = scene.size[0]
    small = scene.resize((round(side * 0.4),) * 2, Image.BOX)
    return _jpeg(small.resize((side, side), Image.BICUBIC).filter(ImageFilter.UnsharpMask(2, 80, 0)))


def _gaussian_camera(scene: Image.Image) -> torch.Tensor:
    """scipy's Gaussian of σ 1.5 px in linear light (numpy's sRGB curve either side) and JPEG 90."""
    x = np.asarray(scene) / 255.0
    linear = gaussian_filter(np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4), (1.5, 1.5, 0))
    y = np.where(linear <= 0.0031308, linear * 12.92, 1.055 * np.clip(linear, 0, 1) ** (1 / 2.4) - 0.055)
    return _jpeg(Image.fromarray(np.clip(y * 255, 0, 255).round().astype(np.uint8)))


def _line(sigma: float, dark: bool = False) -> torch.Tensor:
    """A one-pixel vertical line 220 levels off its ground, blurred by scipy's Gaussian of ``sigma`` px."""
    image = np.full((64, 64), 240.0 if dark else 20.0)
    image[:, 32] = 20.0 if dark else 240.0
    blurred = gaussian_filter(image, (0, sigma)) / 255.0
    return torch.from_numpy(np.repeat(blurred[None], 3, 0))


def test_a_thin_line_reads_the_half_maximum_width_of_its_blur() -> None:
    for dark in (False, True):
        read = []
        for sigma in (1.0, 1.5, 2.0):
            widths = line_widths(_line(sigma, dark))
            assert len(widths) >= 40, (sigma, dark)
            read.append(float(widths.median()))
        # a 1 px line under a Gaussian; at σ 2 the ground 4–7 px away still holds the tail (the line reads 0.17 less)
        expected = [2 * math.sqrt(2 * math.log(2)) * math.sqrt(sigma**2 + 1 / 12) for sigma in (1.0, 1.5)]
        assert all(abs(r - e) <= 0.15 for r, e in zip(read, expected, strict=False)), (read, expected)
        assert read[0] < read[1] < read[2], read
    assert len(line_widths(torch.full((3, 64, 64), 0.5))) == 0
    with pytest.raises(ValueError, match=r"image must be a \(3, H, W\) RGB tensor, got shape \(64, 64\)"):
        line_widths(torch.zeros(64, 64))


def test_the_area_sensor_reads_each_pixel_s_own_area_at_a_non_integer_factor() -> None:
    """Before, the area sampler averaged over bins that overlap at non-integer factors (torch's adaptive pooling):
    6.8 levels RMS from PIL's box reduction and bicubic upscale, its lines 0.55 px wider."""
    scenes = _strokes(1, count=4)
    pil = [_tensor(s.resize((round(SIDE * 0.4),) * 2, Image.BOX).resize((SIDE, SIDE), Image.BICUBIC)) for s in scenes]
    ours = [resolution_image(_tensor(s), 0.4, "catmull_rom", "area") for s in scenes]
    rms = math.sqrt(sum(float((a.float() - b.float()).pow(2).mean()) for a, b in zip(ours, pil, strict=True)) / 4)
    assert rms <= 1.0
    lines = [float(torch.cat([line_widths(image) for image in images]).median()) for images in (ours, pil)]
    assert abs(lines[0] - lines[1]) <= 0.1, lines


def test_an_area_sensor_comes_before_the_sharpening_in_the_chain() -> None:
    assert AREA_ORDER.index(Resolution.name) < AREA_ORDER.index(Sharpen.name)
    assert AREA_ORDER.index(Blur.name) < AREA_ORDER.index(Resolution.name)


def test_the_distance_weighs_both_widths_and_needs_enough_of_them() -> None:
    widths = [torch.full((30,), 3.0, dtype=torch.float64)] * 2
    real = SetWidths(widths, [w + 1 for w in widths], torch.zeros(2, 8))
    near = SetWidths([w + 0.1 for w in widths], [w + 1 for w in widths], torch.zeros(2, 8))
    value, parts = distance(near, real)
    assert value == pytest.approx(1.0) and parts == {"steps": 0.1, "lines": 0.0, "spectrum": 0.0}
    assert math.isinf(distance(near, real, slice(0, 1))[0])  # 30 steps in one image: fewer than MIN_COUNT
    assert MIN_COUNT > 30


def test_the_search_finds_a_sensor_and_a_sharpening_that_trade_against_each_other() -> None:
    grid = (
        ("scale", (1 / 3, 0.5)),
        ("amount", (0.0, 1.0, 2.0)),
        ("sharpen_sigma", (1.0,)),
        ("kernel", ("bicubic", "lanczos")),
    )
    best = descend(lambda c: abs(c.scale - 1 / 3) + abs(c.amount - 2.0) + (c.kernel != "lanczos"), grid)
    assert (best.scale, best.amount, best.kernel) == (1 / 3, 2.0, "lanczos")


@pytest.mark.slow
def test_a_sensor_read_by_area_upscaled_and_sharpened_is_found() -> None:
    """Before: no step looked for it; the blur alone (0.925 px) left the lines 0.09 px wide of the captures' and
    the steps 0.23 px, the low bands 1.08 (mean squared log2) off. Now: a sensor of 0.4, sharpened after its upscale."""
    captures = [_sensor_camera(scene) for scene in _strokes(2)]
    clean = [_tensor(scene) for scene in _strokes(1)]
    profile = fit_unpaired(captures, clean, effects=("resolution", "blur", "sharpen"), area_sensor=True)
    record = profile.fitted["effects"]["area_sensor"]
    sensor = next(effect for effect in profile.effects if effect.name == "resolution")
    assert record["kept"] and sensor.sample == "area" and float(sensor.scale) == pytest.approx(0.4), record
    names = [effect.name for effect in profile.effects]
    assert names.index("resolution") < names.index("sharpen"), names
    real, simulated = set_widths(captures), set_widths(profile.simulate(clean, 0, eight_bit=True))
    now = distance(simulated, real)[1]
    assert abs(now["steps"]) <= 0.15 and abs(now["lines"]) <= 0.15 and now["spectrum"] <= 0.05, now


@pytest.mark.slow
def test_a_gaussian_blur_camera_gets_no_sensor() -> None:
    captures = [_gaussian_camera(scene) for scene in _strokes(2)]
    clean = [_tensor(scene) for scene in _strokes(1)]
    profile = fit_unpaired(captures, clean, effects=("resolution", "blur", "sharpen"), area_sensor=True)
    record = profile.fitted["effects"]["area_sensor"]
    assert not record["kept"], record
    assert [effect.name for effect in profile.effects] == ["blur"]


def test_the_area_sensor_is_searched_only_when_asked_for() -> None:
    """Off by default (its module says why): the step is configured by ``fit_unpaired``'s ``area_sensor``, a bool."""
    steps = with_sensor(UNPAIRED_STEPS, None, False)
    searching = [step.search for _, step in steps if isinstance(step, AreaSensorMatch)]
    assert searching == [False]
    assert [
        step.search for _, step in with_sensor(UNPAIRED_STEPS, None, True) if isinstance(step, AreaSensorMatch)
    ] == [True]
    with pytest.raises(TypeError, match=r"area_sensor must be a bool, got area_sensor='yes' \(str\)"):
        check_area_sensor("yes")


def test_a_default_fit_of_the_sensor_camera_records_no_area_sensor() -> None:
    captures = [_sensor_camera(scene) for scene in _strokes(2, count=8)]
    clean = [_tensor(scene) for scene in _strokes(1, count=8)]
    profile = fit_unpaired(captures, clean, effects=("resolution", "blur"))
    assert "area_sensor" not in profile.fitted["effects"]
    assert all(getattr(effect, "sample", None) != "area" for effect in profile.effects)
