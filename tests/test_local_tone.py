"""The tone curve on a base layer (``Tone(base_sigma=...)``,
:func:`camdegrade.functional.isp.local_tone.local_tone_image`) and the unpaired fit's step that chooses it
(:mod:`camdegrade.fitting.unpaired.steps.local_tone`): the detail a global curve leaves follows the scene's
brightness, a local curve's does not, and the fit tells the two cameras apart from their photos of other scenes."""

from __future__ import annotations

import math

import pytest
import torch

from camdegrade import CameraProfile, load_profile
from camdegrade._support.pixels import unit_to_bytes
from camdegrade.effects import Tone
from camdegrade.effects.chain import apply_effects
from camdegrade.fitting.unpaired import fit_unpaired
from camdegrade.fitting.unpaired.steps.local_tone import detail_by_brightness, tilt
from camdegrade.functional.isp.local_tone import local_tone_image
from camdegrade.synthetic import dead_leaves_images

torch.set_num_threads(1)


def _grating(level: float, amplitude: float = 0.02, size: int = 64) -> torch.Tensor:
    """A flat ``level`` with a vertical sine grating of period 4 px."""
    x = torch.arange(size, dtype=torch.float32)
    wave = amplitude * torch.sin(2 * math.pi * x / 4)
    return (level + wave).expand(1, 3, size, size).contiguous()


def _amplitude(image: torch.Tensor) -> float:
    row = image[0, 1, 32, 16:48]
    return float(row.max() - row.min()) / 2


def test_a_local_curve_keeps_one_detail_gain_where_a_global_curve_follows_the_brightness() -> None:
    dark, bright = _grating(0.15), _grating(0.8)
    global_curve, local_curve = Tone(gamma=2.0), Tone(gamma=2.0, base_sigma=4.0)
    # the global curve's slope: 2·0.15 = 0.3 on the dark grating, 1.6 on the bright one
    ratio_global = _amplitude(global_curve(bright)) / _amplitude(global_curve(dark))
    assert ratio_global == pytest.approx(0.8 / 0.15, rel=0.05)
    # the local curve: both at its mean slope f(1) − f(0) = 1, so the amplitude stays 0.02 (within a sample's phase)
    for grating in (dark, bright):
        assert _amplitude(local_curve(grating)) == pytest.approx(0.02, rel=0.05)
    # the brightness itself is the curve's: the mean of a period
    assert float(local_curve(bright)[..., 16:48].mean()) == pytest.approx(0.8**2, abs=0.005)


def test_sigma_zero_and_flat_images_give_the_global_curve() -> None:
    image = torch.rand(2, 3, 24, 24, generator=torch.Generator().manual_seed(0))
    values = (1.3, -0.05, 1.1, 0.4)
    assert torch.equal(local_tone_image(image, 0.0, *values), Tone(*values)(image))
    flat = torch.full((1, 3, 20, 20), 0.37)
    assert torch.allclose(Tone(*values, base_sigma=3.0)(flat), Tone(*values)(flat), atol=1e-6)


def test_a_chain_runs_it_as_forward_and_a_profile_file_keeps_it(tmp_path) -> None:
    image = torch.rand(1, 3, 32, 32, generator=torch.Generator().manual_seed(1))
    tone = Tone(1.2, 0.02, 0.97, 0.5, base_sigma=3.0)  # an exposure: a global curve runs it on linear light
    assert torch.allclose(apply_effects([tone], [{}], image.clone()), tone(image), atol=1e-6)
    assert tone.config()["base_sigma"] == 3.0 and "base_sigma" not in Tone(1.2).config()  # old files unchanged
    path = CameraProfile(None, [tone], name="local").save(tmp_path / "local.safetensors")
    loaded = load_profile(path)
    assert loaded.effects[0].base_sigma == 3.0
    assert torch.equal(loaded(image), CameraProfile(None, [tone])(image))


def test_bad_base_sigma_is_refused_by_name() -> None:
    with pytest.raises(ValueError, match="base_sigma"):
        Tone(base_sigma=-1.0)
    with pytest.raises(ValueError, match="base_sigma"):
        Tone(base_sigma=100.0).check_values()
    with pytest.raises(ValueError, match="sigma"):
        local_tone_image(torch.zeros(1, 3, 8, 8), -2.0)


def _scenes(seed: int, count: int = 12, size: int = 160) -> list[torch.Tensor]:
    """Dead-leaves scenes with a fine grain of ±4 levels (a surface's texture: what a curve's slope scales)."""
    generator = torch.Generator().manual_seed(seed)
    leaves = dead_leaves_images(count, size, seed=seed)
    grain = [(torch.rand(1, size, size, generator=generator) - 0.5) / 32 for _ in leaves]
    return [unit_to_bytes(image / 255 + noise) for image, noise in zip(leaves, grain, strict=True)]


def _photos(tone: Tone, seed: int, count: int = 12, size: int = 160) -> list[torch.Tensor]:
    scenes = [image.float() / 255 for image in _scenes(seed, count, size)]
    return [unit_to_bytes(image) for image in CameraProfile(None, [tone]).simulate(scenes, seed=3)]


def test_the_tilt_reads_the_global_curve_against_a_local_camera() -> None:
    clean = [image.float() / 255 for image in _scenes(1)]
    local_camera = [image.float() / 255 for image in _photos(Tone(gamma=2.0, base_sigma=4.0), seed=2)]
    captured = torch.stack([detail_by_brightness(image) for image in local_camera]).sum(0)

    def simulated(tone: Tone) -> torch.Tensor:
        return torch.stack([detail_by_brightness(tone(image[None])[0]) for image in clean]).sum(0)

    global_tilt, local_tilt = (
        tilt(simulated(Tone(gamma=2.0)), captured),
        tilt(simulated(Tone(2.0, base_sigma=4.0)), captured),
    )
    assert float(global_tilt) > 0.4 and float(local_tilt) < 0.15, (global_tilt, local_tilt)


@pytest.mark.slow
@pytest.mark.parametrize("base_sigma", [0.0, 4.0])
def test_the_unpaired_fit_keeps_a_local_curve_for_a_local_camera_only(base_sigma: float) -> None:
    clean = _scenes(1, 24, 256)
    captures = _photos(Tone(gamma=2.5, base_sigma=base_sigma), seed=2, count=24, size=256)
    profile = fit_unpaired(captures, clean, effects=["tone"])
    record = profile.fitted["effects"]["local_tone"]
    tone = next(effect for effect in profile.effects if effect.name == "tone")
    assert record["kept"] == (base_sigma > 0) and tone.base_sigma == record["base_sigma"], record


def test_too_few_pixels_leave_the_tilt_not_measurable() -> None:
    """PolyU's ten 128² crops: each half of the sets held too few pixels per brightness band, the tilt read 0 on
    every half, so its split-half error was 0 and a local curve was kept on the whole sets' tilt alone."""
    small = torch.stack([detail_by_brightness(image.float() / 255) for image in _scenes(1, 2, 96)]).sum(0)
    assert math.isnan(float(tilt(small, small)))
