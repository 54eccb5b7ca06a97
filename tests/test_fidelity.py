"""Fidelity measures (grid, texture bands, flat noise) and the image-only critic."""

from __future__ import annotations

import json
import math

import pytest
import torch

from camdegrade.functional.analysis.images import radial_frequency
from camdegrade.functional.optics.blur import blur_image
from camdegrade.measures.critic import critic_test
from camdegrade.measures.fidelity import (
    BAND_EDGES,
    FidelityReport,
    band_log2_ratios,
    grid_rms,
    measure_fidelity,
)


def _textured(seed: int, size: int = 128, fine_share: float = 0.1) -> torch.Tensor:
    """A seeded image with texture at every frequency: smoothed noise plus ``fine_share`` of fine noise."""
    generator = torch.Generator().manual_seed(seed)
    coarse = blur_image(torch.rand(1, 3, size, size, generator=generator), 2.0)
    fine = torch.rand(1, 3, size, size, generator=generator) - 0.5
    return (0.2 + 0.6 * coarse + fine_share * fine).clamp(0, 1)


def _grid_pattern(levels: float) -> torch.Tensor:
    """A zero-mean 4×4-periodic luma pattern of RMS ``levels`` (8-bit), separable so that a 9×9 box mean (two
    periods and one line along each axis) leaves it nearly untouched."""
    rows = torch.tensor([1.0, -1.0, 1.0, -1.0])
    cols = torch.tensor([1.0, 1.0, -1.0, -1.0])
    tile = rows[:, None] * cols[None, :]  # RMS 1
    return tile.repeat(64, 64) * levels / 255.0


def test_grid_rms_of_a_known_pattern():
    pattern = _grid_pattern(2.0)
    image = (0.5 + pattern).expand(1, 3, -1, -1)
    assert grid_rms(image) == pytest.approx(2.0, rel=0.05)


def test_grid_rms_of_random_noise_is_near_zero():
    noise = torch.randn(1, 3, 256, 256, generator=torch.Generator().manual_seed(0)) * (10 / 255)
    assert grid_rms((0.5 + noise).clamp(0, 1)) < 0.15  # noise of 10 levels: about 10 / 64 left in a phase mean


def test_grid_rms_sees_a_grid_under_noise():
    noise = torch.randn(1, 3, 256, 256, generator=torch.Generator().manual_seed(1)) * (3 / 255)
    with_grid = (0.5 + noise + _grid_pattern(1.0)).clamp(0, 1)
    assert grid_rms(with_grid) == pytest.approx(1.0, abs=0.1)


@pytest.mark.parametrize("height,width", [(8, 8), (7, 10)])
def test_the_radial_frequency_of_an_rfft_grid(height: int, width: int):
    """DC is 0, a row's last coefficient of an even width is Nyquist (0.5), and every coefficient of the rfft grid
    is ``sqrt(fy² + fx²)`` in cycles/pixel, whatever the frame's parity."""
    radius = radial_frequency(height, width)
    assert radius.shape == (height, width // 2 + 1)
    assert radius[0, 0] == 0
    fy = [min(i, height - i) / height for i in range(height)]
    fx = [j / width for j in range(width // 2 + 1)]
    expected = torch.tensor([[math.hypot(y, x) for x in fx] for y in fy])
    torch.testing.assert_close(radius, expected, rtol=0, atol=1e-6)
    if width % 2 == 0:
        assert radius[0, -1] == 0.5
    assert radial_frequency(height, width, torch.float64).dtype == torch.float64


def test_band_ratios_of_an_image_with_itself_are_zero():
    image = _textured(0)
    assert band_log2_ratios(image, image) == [0.0] * (len(BAND_EDGES) - 1)


def test_band_ratios_of_a_blurred_copy_fall_with_frequency():
    image = _textured(1)
    ratios = band_log2_ratios(blur_image(image, 1.0), image)
    assert all(value < -1.0 for value in ratios[2:])
    assert ratios[0] > ratios[2] > ratios[4]


def test_band_ratios_of_a_sharpened_copy_are_positive_at_high_frequency():
    image = _textured(2)
    sharpened = (image + 0.5 * (image - blur_image(image, 1.0))).clamp(0, 1)
    ratios = band_log2_ratios(sharpened, image)
    assert all(value > 0.2 for value in ratios[2:])
    assert abs(ratios[0]) < 0.2


def test_band_ratios_of_flat_frames_are_not_measurable():
    flat = torch.full((1, 3, 64, 64), 0.5)
    assert band_log2_ratios(flat, flat) == [None] * (len(BAND_EDGES) - 1)


def test_band_ratios_refuse_different_shapes():
    with pytest.raises(ValueError, match="same shape"):
        band_log2_ratios(torch.rand(1, 3, 32, 32), torch.rand(1, 3, 32, 48))


def test_grid_rms_refuses_a_grey_image():
    with pytest.raises(ValueError, match=r"image must be a float image \[N, 3, H, W\]"):
        grid_rms(torch.rand(1, 1, 32, 32))


def _flat_with_noise(seed: int, std: float, size: int = 160) -> tuple[torch.Tensor, torch.Tensor]:
    clean = torch.full((3, size, size), 0.5)
    noise = torch.randn(3, size, size, generator=torch.Generator().manual_seed(seed)) * (std / 255)
    return clean, (clean + noise).clamp(0, 1)


def test_measure_fidelity_reads_twice_the_noise_and_no_grid():
    cleans, reals, sims = [], [], []
    for seed in range(2):
        clean, real = _flat_with_noise(seed, 2.0)
        _, sim = _flat_with_noise(seed + 10, 4.0)
        cleans, reals, sims = [*cleans, clean], [*reals, real], [*sims, sim]
    report = measure_fidelity(sims, reals, cleans)
    assert report.frames == 2
    assert report.noise_ratio == pytest.approx(2.0, rel=0.05)
    assert report.flat_pixels > 2000
    assert report.grid_sim < 0.2 and report.grid_real < 0.1
    assert all(value == pytest.approx(2.0, abs=0.15) for value in report.bands[1:])  # white noise: 4× the power
    assert report.psnr == pytest.approx(10 * math.log10(255**2 / 20), abs=0.3)  # error variance 2² + 4²


def _flat_rows(offsets_levels: torch.Tensor) -> torch.Tensor:
    """A flat grey 8-bit frame (96²) whose rows are offset by ``offsets_levels`` (96 values), as [0, 1] floats."""
    return ((128 + offsets_levels)[None, :, None].expand(3, 96, 96).round() / 255).clone()


def test_banding_of_flat_rows_is_one_and_of_striped_rows_is_read():
    capture = _flat_rows(torch.zeros(96))  # a noiseless 8-bit camera: its rows do not vary at all
    generator = torch.Generator().manual_seed(0)
    flips = (torch.rand(3, 96, 96, generator=generator) < 0.03).float() / 255  # 3 % of pixels a level up
    rounding = capture + flips  # row means 0.03 ± 0.02 levels: rounding, not banding
    striped = _flat_rows(torch.randint(0, 2, (96,), generator=generator).float())  # rows of 128 or 129 levels
    assert measure_fidelity([rounding], [capture], [capture]).banding_ratio == 1.0
    banded = measure_fidelity([striped], [capture], [capture]).banding_ratio
    assert banded is not None and banded > 5  # about 0.5 levels over the 0.05 floor


def test_fidelity_report_is_strict_json_with_none_where_not_measurable():
    clean = torch.full((3, 32, 32), 0.5)  # too few flat pixels once eroded: noise and banding not measurable
    report = measure_fidelity([clean], [clean], [clean])
    assert isinstance(report, FidelityReport)
    assert report.noise_ratio is None and report.banding_ratio is None and report.grid_ratio is None
    text = json.dumps(report.to_dict(), allow_nan=False)
    assert json.loads(text)["band_edges"] == list(BAND_EDGES)


def test_measure_fidelity_refuses_lists_of_different_lengths():
    with pytest.raises(ValueError, match="as long"):
        measure_fidelity([torch.rand(3, 8, 8)], [], [])


def _critic_sets(noise_std: float, seed: int, pairs: int = 6) -> tuple[list, list, list]:
    """``pairs`` smooth clean images, 'real' = clean + noise of 4 levels, 'sim' = clean + ``noise_std`` levels."""
    generator = torch.Generator().manual_seed(seed)
    cleans = [_textured(seed * 100 + index, 64, fine_share=0.0)[0] for index in range(pairs)]
    reals = [(c + torch.randn(c.shape, generator=generator) * (4 / 255)).clamp(0, 1) for c in cleans]
    sims = [(c + torch.randn(c.shape, generator=generator) * (noise_std / 255)).clamp(0, 1) for c in cleans]
    return cleans, reals, sims


def _image_only_accuracy(noise_std: float) -> float:
    calibration = _critic_sets(noise_std, seed=1)
    held_out = _critic_sets(noise_std, seed=2)
    return critic_test(calibration, held_out, seed=0, steps=120, image_only=True).accuracy


def test_image_only_critic_cannot_tell_two_draws_of_one_distribution():
    assert 0.35 < _image_only_accuracy(4.0) < 0.65


def test_image_only_critic_tells_noise_from_no_noise():
    assert _image_only_accuracy(0.0) > 0.9


def test_image_only_critic_never_sees_the_clean_image():
    from camdegrade.measures.critic import IMAGE_ONLY_PLANES, Patches

    cleans, reals, sims = _critic_sets(4.0, seed=3, pairs=1)
    one = Patches.sample(cleans, reals, sims, 0, "check", image_only=True)
    other = Patches.sample([torch.zeros_like(cleans[0])], reals, sims, 0, "check", image_only=True)
    assert one.inputs.shape[1] == IMAGE_ONLY_PLANES
    assert torch.equal(one.inputs, other.inputs)
