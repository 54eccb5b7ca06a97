"""The quantization effect: its kernel, its fit from the code histogram, its place in a chain, and the ``comb``
family that signals it."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import Tensor

from camdegrade.effects import Noise, Quantization, Resolution, Sharpen, Vignetting
from camdegrade.functional.isp.quantization import (
    code_histogram,
    histogram_peaks,
    quantize_image,
    skipped_runs,
    uniform_codebook,
)
from camdegrade.measures import FAMILIES, MeasuredPair
from camdegrade.profile import CameraProfile
from effects_images import photo, photo_batch


def _curve(levels: int) -> Tensor:
    """``(3, levels)``: a contrast S-curve (slope 1.25 at mid-grey) at ``levels`` evenly spaced values."""
    x = torch.linspace(0, 1, levels, dtype=torch.float64)
    return (x - 0.25 * torch.sin(2 * torch.pi * x) / (2 * torch.pi)).float().expand(3, levels).clone()


def _noisy_photos(count: int = 4, std: float = 2.0) -> list[Tensor]:
    """Photos with Gaussian noise of ``std`` 8-bit levels (a camera's noise dithers the histogram)."""
    generator = torch.Generator().manual_seed(0)
    images = [photo(name, 160) for name in ("astronaut", "coffee", "chelsea", "rocket")][:count]
    return [(image + torch.randn(image.shape, generator=generator) * std / 255).clamp(0, 1) for image in images]


def _comb(images: list[Tensor]) -> Tensor:
    family = FAMILIES["comb"]
    sums = [family.measure(MeasuredPair(image, image)) for image in images]
    return family.reduce(sum(num for num, _ in sums).double(), sum(den for _, den in sums).double())


def test_a_uniform_codebook_rounds_to_that_many_levels() -> None:
    image = photo_batch()
    for levels in (2, 32, 256):
        scaled = image.double() * (levels - 1)
        expected = torch.round(scaled) / (levels - 1)
        out = quantize_image(image, uniform_codebook(levels))
        clear = ((scaled - scaled.floor()) - 0.5).abs() > 1e-4  # away from a tie between two levels
        assert (out - expected).abs()[clear].max() < 1e-6 and len(out[:, 0].unique()) <= levels
        assert (out - image).abs().max() <= 0.5 / (levels - 1) + 1e-6


def test_a_curved_codebook_holds_only_its_values_and_keeps_dtype() -> None:
    codebook = _curve(32)
    image = photo_batch()
    out = quantize_image(image, codebook)
    for channel in range(3):
        assert set(out[:, channel].unique().tolist()) <= set(codebook[channel].tolist())
    assert (out - image).abs().max() <= 0.5 * float(codebook[0].diff().max()) + 1e-6
    as_bytes = quantize_image((image * 255).round().byte(), codebook)
    assert as_bytes.dtype == torch.uint8 and as_bytes.shape == image.shape
    assert torch.equal(quantize_image(image[None], codebook)[0], out)  # any leading dims


def test_kernel_errors_name_the_argument() -> None:
    with pytest.raises(ValueError, match=r"codebook must have shape \(3, L\) with L >= 1, got \(2, 4\)"):
        quantize_image(photo_batch(), torch.zeros(2, 4))
    with pytest.raises(ValueError, match="codebook must be non-decreasing"):
        quantize_image(photo_batch(), torch.tensor([[0.0, 1.0, 0.5]] * 3))
    with pytest.raises(ValueError, match="levels must be an integer from 2 to 256, got levels=1"):
        Quantization(1)
    with pytest.raises(ValueError, match=r"codebook must have shape \(3, 8\), got shape \(3, 4\)"):
        Quantization(8, uniform_codebook(4))
    with pytest.raises(ValueError, match="codebook must be non-decreasing along each row"):
        Quantization(3, torch.tensor([[0.0, 0.6, 0.5]] * 3))
    with pytest.raises(ValueError, match="codebook must be from 0 to 1"):
        Quantization(2, torch.tensor([[0.0, 1.5]] * 3))
    with pytest.raises(ValueError, match=r"scale must be from 0\.125 to 1, got scale=0\.1"):
        Quantization(32, scale=0.1)


def test_peaks_and_runs_of_a_combed_histogram() -> None:
    images = [quantize_image(image, _curve(32)) for image in _noisy_photos()]
    histogram = sum(code_histogram(image) for image in images)
    levels = (_curve(32)[0].double() * 255).round()
    inside = levels[(levels >= 1) & (levels <= 254)]
    found = (histogram_peaks(histogram[1]) * 255).round()
    assert len(found) == 32 and (found - levels).abs().max() <= 1.0
    assert float(skipped_runs(histogram[1]).double().median()) >= 4  # levels 6–10 codes apart
    assert len(inside) == 30


def test_fit_recovers_the_levels_before_a_tone_curve() -> None:
    sources = _noisy_photos()
    targets = [quantize_image(source, _curve(32)) for source in sources]
    fitted = Quantization.fit(sources, targets)
    assert fitted.levels == 32 and fitted.bits == 5.0
    assert (fitted.codebook - _curve(32)).abs().max() * 255 <= 1.0
    fitted_uniform = Quantization.fit(sources, [quantize_image(source, uniform_codebook(16)) for source in sources])
    assert fitted_uniform.levels == 16


def test_fit_finds_nothing_on_a_smooth_histogram_or_a_tone_table() -> None:
    sources = _noisy_photos()
    assert Quantization.fit(sources, sources).levels == 256
    # An 8-bit buffer through a contrast table: single codes skipped where it is steeper than 1.
    table = _curve(256)[0]
    tabled = [table[(source * 255).round().long()] for source in sources]
    assert float(skipped_runs(sum(code_histogram(t) for t in tabled)[1]).double().median()) == 1
    assert Quantization.fit(sources, tabled).levels == 256


def test_strength_moves_the_levels_apart_and_zero_is_neutral() -> None:
    stage = Quantization(32, _curve(32))
    assert stage.scaled(0.5).levels == 63 and stage.scaled(2.0).levels == 17
    assert stage.scaled(0.01).levels == Quantization.MAX_FITTED_LEVELS and stage.scaled(0.0).levels == 256
    assert stage.magnitude() == pytest.approx(np.log2(255 / 31))
    assert Quantization().magnitude() == 0.0


def test_it_is_added_at_the_end_of_the_isp() -> None:
    profile = CameraProfile(None, [Vignetting(-0.3), Noise(0.01), Resolution(0.5), Sharpen(1.0, 0.5)])
    added = profile.with_effects(Quantization(32, scale=0.5))
    assert [effect.name for effect in added.effects] == ["vignetting", "noise", "resolution", "sharpen", "quantization"]


def test_on_a_grid_flat_regions_take_their_level_and_steps_are_smooth() -> None:
    """A buffer quantized at half the resolution and upscaled: a flat region is its level, as on every pixel; a
    ramp's steps are spread over the upscale's kernel (codes between the levels occur), unlike on every pixel."""
    codebook = uniform_codebook(16)
    flat = torch.full((1, 3, 32, 32), 0.41)
    assert torch.allclose(quantize_image(flat, codebook, 0.5), quantize_image(flat, codebook), atol=1e-6)
    ramp = torch.linspace(0, 1, 128).expand(1, 3, 32, 128).clone()
    on_grid, per_pixel = quantize_image(ramp, codebook, 0.5), quantize_image(ramp, codebook)
    assert len(per_pixel[0, 0].unique()) == 16 and len((on_grid[0, 0] * 255).round().unique()) > 40
    assert (on_grid - ramp).abs().max() <= 1.5 / 15


def test_comb_family_tells_a_coarse_buffer_from_noise() -> None:
    sources = _noisy_photos()
    smooth = _comb(sources)
    combed = _comb([quantize_image(source, _curve(32)) for source in sources])
    assert bool((smooth < 0.1).all()) and bool((combed > 1.0).all())
    upscaled = [Resolution(0.5)(quantize_image(Resolution(0.5)(s[None]), _curve(32)))[0] for s in sources]
    family = FAMILIES["comb"]
    assert bool((family.compare(_comb(upscaled)) - family.compare(smooth) > family.tau).all())


def _foreign_pairs(base: str, count: int = 16) -> tuple[list[Tensor], list[Tensor], np.ndarray]:
    """The base camera's captures and its quantization scenario's (a 5-bit buffer before its tone table) of the same
    scenes with the same draws, and the scenario's table at the 32 levels (the codes its output holds)."""
    from foreign_cameras import SCENARIOS, scenes
    from foreign_cameras.stages import ToneLUT

    cleans = scenes(count, 128, seed=303)
    quantized = SCENARIOS[base]["quantization"].camera()
    cameras = (SCENARIOS[base]["control"].camera(), quantized)
    images = [
        [torch.from_numpy(camera(clean, seed=(303, i)).transpose(2, 0, 1).copy()) for i, clean in enumerate(cleans)]
        for camera in cameras
    ]
    table = next(stage for stage in quantized.stages if isinstance(stage, ToneLUT)).table()
    return images[0], images[1], table[np.round(np.arange(32) / 31 * 255).astype(int)]


@pytest.mark.slow
def test_fit_recovers_the_bits_of_foreign_cameras() -> None:
    """A foreign camera's 5-bit buffer before its tone table (tests/foreign_cameras, no camdegrade code): on the
    phone (nothing after the table) every one of the 32 levels to the code; on the webcam, whose 2× bicubic upscale
    of the buffer fills the codes between the levels, 31–32 levels per channel: the bright 16 of them found to within
    2 codes (but one of 48: 7 codes off, in blue), the dark ones, where the noise is strongest relative to their
    spacing, less well; on either base without the buffer, none."""
    phone_base, phone, levels = _foreign_pairs("phone")
    fitted = Quantization.fit(phone_base, phone)
    assert fitted.levels == 32 and fitted.bits == 5.0
    assert torch.equal((fitted.codebook * 255).round().int(), torch.from_numpy(levels).int().expand(3, 32))
    assert Quantization.fit(phone_base, phone_base).levels == 256
    webcam_base, webcam, levels = _foreign_pairs("webcam")
    fitted = Quantization.fit(webcam_base, webcam)
    assert abs(fitted.bits - 5.0) < 0.15
    found = (fitted.codebook * 255).round()
    nearest = (found[:, :, None] - torch.from_numpy(levels[-16:]).double()).abs().amin(1)  # per bright level
    assert int((nearest <= 2).sum()) >= 46 and int((nearest == 0).sum()) >= 40  # of 48 (16 levels, 3 channels)
    assert Quantization.fit(webcam_base, webcam_base).levels == 256
