"""A sensor with fewer pixels than the output: its kernel and effect, the trace its upscale leaves in the captures
(found from the images alone), and a fit that trains its network through the stage it finds."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F
from torch import Tensor

from camdegrade import VirtualCamera
from camdegrade._support.recipes import MIN_SENSOR_SCALE
from camdegrade.effects import JPEG, Blur, Noise, Resolution
from camdegrade.effects.isp.resolution import SCALES
from camdegrade.errors import CamdegradeError
from camdegrade.fitting import FitConfig, fit_profile
from camdegrade.fitting.network.training import _sensor_crop, fit_network, random_crop_batch
from camdegrade.fitting.steps.resolution import SENSOR_SAMPLING
from camdegrade.functional import resolution_image
from camdegrade.measures.metrics import psnr
from camdegrade.measures.traces.resampling import MIN_EXCESS, resampling_trace
from camdegrade.synthetic import dead_leaves_images


def eight_bit(image: Tensor) -> Tensor:
    return (image.clamp(0, 1) * 255).round() / 255


def leaves(count: int = 16, size: int = 128, seed: int = 0) -> list[Tensor]:
    return [image.float() / 255 for image in dead_leaves_images(count, size, seed=seed)]


def test_scale_one_is_the_identity_and_uint8_stays_uint8() -> None:
    image = leaves(1, 32)[0]
    assert torch.equal(resolution_image(image, 1.0), image)
    as_bytes = (image * 255).round().to(torch.uint8)
    out = resolution_image(as_bytes, 0.5)
    assert out.dtype == torch.uint8 and out.shape == as_bytes.shape


def test_half_resolution_loses_the_top_octave_and_keeps_the_low_one() -> None:
    """A sinusoid below the sensor's Nyquist (0.25 cycles/pixel at scale 0.5) survives; one above it does not."""
    x = torch.arange(64, dtype=torch.float32)
    for frequency, kept in ((0.05, True), (0.4, False)):
        wave = 0.5 + 0.25 * torch.cos(2 * torch.pi * frequency * x)
        image = wave.expand(3, 64, 64).clone()
        out = resolution_image(image, 0.5)
        amplitude = float((out[0, 32, 16:48] - 0.5).abs().max())
        assert (amplitude > 0.2) if kept else (amplitude < 0.1), (frequency, amplitude)


@pytest.mark.parametrize("scale", SCALES)
def test_fit_finds_the_scale_of_a_target_it_made(scale: float) -> None:
    sources = leaves(3, 96)
    targets = [resolution_image(source, scale) for source in sources]
    assert float(Resolution.fit(sources, targets).scale) == pytest.approx(scale)


def test_fit_of_a_target_that_is_the_source_is_the_full_resolution() -> None:
    sources = leaves(3, 96)
    assert float(Resolution.fit(sources, sources).scale) == 1.0


@pytest.mark.parametrize(
    ("scale", "period"), [(1.0, 1), (0.5, 2), (1 / 3, 3), (0.25, 4), (2 / 3, 3), (0.75, 4), (0.3, 10), (0.9, 10)]
)
def test_period_is_the_sensor_grid_in_output_pixels(scale: float, period: int) -> None:
    assert Resolution(scale).period == period


def test_scaled_and_magnitude() -> None:
    half = Resolution(0.5)
    assert half.magnitude() == pytest.approx(1.0)
    assert float(half.scaled(0.0).scale) == 1.0
    assert float(half.scaled(2.0).scale) == pytest.approx(0.25)
    assert float(Resolution(0.125).scaled(3.0).scale) == pytest.approx(Resolution.MIN_SCALE)


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: Resolution(0.0), "scale must be from 0.125 to 1"),
        (lambda: Resolution(1.5), "scale must be from 0.125 to 1"),
        (lambda: resolution_image(torch.rand(3, 8, 8), 0.0), r"scale must be in \(0, 1\], got scale=0.0"),
        (lambda: resolution_image(torch.rand(3, 8, 8), 0.5, "cubic"), "upsample must be one of"),
        (lambda: resampling_trace([]), "images must hold at least one image"),
        (lambda: resampling_trace([torch.rand(3, 8, 40)]), "images must be at least 16x16 pixels, got 8x40"),
        (lambda: resampling_trace(leaves(1), reference=[]), "reference must hold at least one image"),
        (lambda: resampling_trace([torch.rand(1, 3, 32, 32)]), r"images must be \(3, H, W\) images, got shape"),
        (lambda: resampling_trace([torch.full((3, 32, 32), math.nan)]), "images must be finite"),
        (lambda: FitConfig().replace(sensor_scale=2.0), "sensor_scale must be 'auto' or a number from 0.125 to 1"),
        (lambda: FitConfig().replace(sensor_scale="half"), "sensor_scale must be 'auto' or a number from 0.125 to 1"),
        (
            lambda: FitConfig().replace(effects=("noise", "resolution")),
            "effects: 'resolution' is not fitted after the network",
        ),
        (lambda: FitConfig().replace(arch="paper", sensor_scale=0.5), "sensor_scale=0.5 needs arch='local_affine'"),
        (lambda: fit_profile("no-such-folder", sensor_scale_recipe(0.5), init_from="city100-iphonex"), "init_from"),
        (lambda: random_crop_batch([], 8, 1, torch.Generator(), step=0), "step must be a positive integer, got step=0"),
        (lambda: _sensor_crop(8, Resolution(1 / 3)), "crop must hold two sensor periods .* at least 24, got crop=8"),
    ],
)
def test_bad_values_are_refused_by_name(make, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        make()


def test_the_recipe_bound_is_the_effect_bound() -> None:
    assert MIN_SENSOR_SCALE == Resolution.MIN_SCALE


@pytest.mark.parametrize("period", [2, 3, 4])
def test_the_trace_finds_an_upscale_from_the_images_alone(period: int) -> None:
    upscaled = [eight_bit(resolution_image(image, 1 / period)) for image in leaves()]
    trace = resampling_trace(upscaled)
    assert trace.period == period, trace
    assert trace.coherence[period] - trace.null > MIN_EXCESS + 0.1


@pytest.mark.parametrize("change", ["none", "blur", "noise"])
def test_no_upscale_is_found_where_there_is_none(change: str) -> None:
    """A blur is not an upscale (its spectrum falls without repeating), nor is noise."""
    generator = torch.Generator().manual_seed(0)
    images = leaves()
    if change == "blur":
        images = [Blur(1.2)(image[None])[0] for image in images]
    if change == "noise":
        noise = Noise(a=0.01, b=1e-4)
        images = [noise(image[None], noise.make_params((1, *image.shape), generator))[0] for image in images]
    trace = resampling_trace([eight_bit(image) for image in images])
    assert trace.period is None, trace
    assert max(trace.coherence.values()) - trace.null < MIN_EXCESS - 0.1


def test_jpeg_blocks_are_not_an_upscale_and_an_upscale_under_jpeg_is() -> None:
    """JPEG's 8×8 grid repeats at 1/4 and 1/2 cycles/pixel too: hard-compressed smooth images read 0.47 at 1/2
    (0.02 without the codec) and must not be taken for an upscale; a 2× upscale compressed at quality 75 is."""
    images = leaves(24)
    blocky = [JPEG(20)(Blur(2.0)(image[None]))[0] for image in images]
    trace = resampling_trace(blocky, reference=images)
    assert trace.period is None and trace.coherence[2] > 0.3 and trace.codec > 0.3, trace
    compressed = [JPEG(75)(resolution_image(image, 0.5)[None])[0] for image in images]
    assert resampling_trace(compressed, reference=images).period == 2


def test_the_largest_period_wins_and_sizes_are_weighted_by_their_lines() -> None:
    """A 4× nearest upscale repeats at 1/2 as strongly as at 1/4: it is 4. One large upscaled image does not outvote
    24 small ones without an upscale, nor one large plain image 16 small upscaled ones (each length's bins weigh by
    its number of lines)."""
    nearest = [F.interpolate(image[None, :, ::4, ::4], scale_factor=4, mode="nearest")[0] for image in leaves()]
    assert resampling_trace([eight_bit(image) for image in nearest]).period == 4
    large_upscaled = eight_bit(resolution_image(leaves(1, 384, seed=9)[0], 0.5))
    assert resampling_trace([*leaves(24), large_upscaled]).period is None
    upscaled = [eight_bit(resolution_image(image, 0.5)) for image in leaves()]
    assert resampling_trace([*upscaled, *leaves(1, 384, seed=9)]).period == 2


def test_an_upscale_the_clean_images_already_carry_is_not_the_cameras() -> None:
    upscaled = [eight_bit(resolution_image(image, 0.5)) for image in leaves()]
    darker = [eight_bit(0.5 * image) for image in upscaled]  # a camera that only darkens what it was shown
    assert resampling_trace(darker).period == 2
    trace = resampling_trace(darker, reference=upscaled)
    assert trace.period is None and trace.reference is not None and trace.reference[2] > 0.8, trace
    assert resampling_trace(upscaled, reference=leaves()).period == 2


def sensor_scale_recipe(scale: float) -> FitConfig:
    return FitConfig.recipe("fast", sensor_scale=scale)


@pytest.mark.parametrize(("scale", "crop"), [(0.5, 64), (1 / 3, 60), (0.25, 64), (2 / 3, 60), (0.3, 60)])
def test_windows_hold_whole_sensor_periods(scale: float, crop: int) -> None:
    assert _sensor_crop(64, Resolution(scale)) == crop


def test_crops_start_on_the_sensor_grid() -> None:
    columns = torch.arange(40, dtype=torch.float32).expand(3, 40, 40) / 255
    pairs = [(columns, columns)]
    clean, _ = random_crop_batch(pairs, 8, 64, torch.Generator().manual_seed(0), step=3)
    starts = (clean[:, 0, 0, 0] * 255).round().long()
    assert bool((starts % 3 == 0).all()) and len(set(starts.tolist())) > 3


def _camera_pairs(scale: float, count: int, seed: int) -> list[tuple[Tensor, Tensor]]:
    camera = VirtualCamera([Blur(0.6)], scale=scale)
    generator = torch.Generator().manual_seed(seed)
    cleans = dead_leaves_images(count, 64, seed=seed)
    with torch.no_grad():
        return [(clean, camera(clean, generator=generator)) for clean in cleans]


TINY = {"epochs": 6, "crops_per_pair": 16, "crop": 32, "texture": "none", "effects": ()}


@pytest.mark.slow
def test_a_fit_trains_its_network_through_the_upscale_it_finds() -> None:
    train, held = _camera_pairs(0.5, 24, seed=1), _camera_pairs(0.5, 8, seed=2)
    found = fit_profile(train, FitConfig.recipe("fast", **TINY))
    plain = fit_profile(train, FitConfig.recipe("fast", **TINY, sensor_scale=1.0))
    assert found.fitted["resolution"]["kept"] is True and found.fitted["resolution"]["scale"] == 0.5
    assert [type(effect) for effect in found.effects] == [Resolution]
    assert found.effects[0].sample == SENSOR_SAMPLING == "area"
    assert plain.effects == [] or not any(isinstance(effect, Resolution) for effect in plain.effects)

    def held_psnr(profile) -> float:
        with torch.no_grad():
            outs = [profile(clean[None].float() / 255)[0] for clean, _ in held]
        return sum(psnr(eight_bit(out), captured.float() / 255) for out, (_, captured) in zip(outs, held)) / len(held)

    gained, lost = held_psnr(found), held_psnr(plain)
    assert gained > lost + 0.5, (gained, lost)  # +0.98 dB at this size (AMD EPYC, bfloat16); +3.6 dB fully fitted


def test_a_checkpoint_does_not_resume_through_another_sensor(tmp_path) -> None:
    pairs = _camera_pairs(0.5, 6, seed=1)
    config = FitConfig.recipe("fast", epochs=2, crops_per_pair=2, crop=32)
    checkpoint = tmp_path / "fit.ckpt"
    fit_network(pairs[:4], pairs[4:], config, checkpoint=checkpoint, after=Resolution(0.5))
    with pytest.raises(CamdegradeError, match=r"other training pairs or sensor .* through a sensor at 0\.5x"):
        fit_network(pairs[:4], pairs[4:], config, checkpoint=checkpoint, resume=True)
    with pytest.raises(CamdegradeError, match=r"through a sensor at 0\.25x"):
        fit_network(pairs[:4], pairs[4:], config, checkpoint=checkpoint, resume=True, after=Resolution(0.25))


def test_the_note_says_no_stage_where_the_network_was_dropped() -> None:
    """A camera the clean image already matches (captures = cleans): the network is dropped, and so is the sensor
    the recipe named; the note says so."""
    pairs = [(clean, clean) for clean, _ in _camera_pairs(1.0, 8, seed=3)]
    profile = fit_profile(pairs, FitConfig.recipe("fast", **TINY, sensor_scale=0.5))
    assert profile.network is None and not any(isinstance(effect, Resolution) for effect in profile.effects)
    assert profile.fitted["resolution"]["kept"] is False, profile.fitted["resolution"]


@pytest.mark.slow
def test_a_camera_without_an_upscale_gets_no_stage() -> None:
    profile = fit_profile(_camera_pairs(1.0, 16, seed=1), FitConfig.recipe("fast", **TINY))
    assert profile.fitted["resolution"]["kept"] is False
    assert not any(isinstance(effect, Resolution) for effect in profile.effects)
