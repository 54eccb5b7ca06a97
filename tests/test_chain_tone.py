"""A position-dependent stage judged with the network's output curve refitted through it
(``fitted['effects'][name]['chain_tone']``): a fit of a vignetted camera keeps its vignetting and the captures' tone
over whole frames, where the network had learned the vignetted frames' mean tone from windows and the vignetting
stage, fitted after it with an exposure it then drops, darkened the frames again (the foreign webcam:
docs/results.md, *The webcam base fit's own tone misfit*).

The camera here is numpy only (not camdegrade's kernels): sRGB decode, cos⁴ vignetting of 35° at the corners, sRGB
encode, 8 bits."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from PIL import Image
from torch import Tensor

from camdegrade.effects import Resolution, Vignetting
from camdegrade.fitting import FitConfig, fit_profile
from camdegrade.fitting.network import chain_tone
from camdegrade.fitting.steps.effects import retoned
from camdegrade.network import LocalAffineNet
from camdegrade.profile import CameraProfile

RECIPE = FitConfig(epochs=2, crop=64, batch_size=4, crops_per_pair=8, val_fraction=0.34).replace(
    effects=("vignetting",), texture="none", sensor_scale=1.0
)


def _srgb_to_linear(x: np.ndarray) -> np.ndarray:
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def _linear_to_srgb(x: np.ndarray) -> np.ndarray:
    return np.where(x <= 0.0031308, x * 12.92, 1.055 * np.power(np.maximum(x, 0.0031308), 1 / 2.4) - 0.055)


def _cos4(size: int, corner_degrees: float) -> np.ndarray:
    y, x = np.mgrid[:size, :size] - (size - 1) / 2
    radius = np.hypot(y, x) / np.hypot((size - 1) / 2, (size - 1) / 2)
    return np.cos(np.arctan(radius * np.tan(np.radians(corner_degrees)))) ** 4


def _vignetted_pairs(count: int = 12, size: int = 128, corner_degrees: float = 30.0) -> list[tuple[Tensor, Tensor]]:
    """Scenes of smooth colour (a 6×6 grid of random colours, bicubic) and fine texture, 8-bit, captured through
    cos⁴ vignetting in linear light."""
    rng = np.random.default_rng(0)
    falloff = _cos4(size, corner_degrees)[..., None]
    pairs = []
    for _ in range(count):
        grid = Image.fromarray(rng.integers(25, 230, (6, 6, 3), dtype=np.uint8)).resize((size, size), Image.BICUBIC)
        clean = np.round(np.clip(np.asarray(grid) / 255 + rng.normal(0, 0.04, (size, size, 3)), 0, 1) * 255) / 255
        captured = np.round(np.clip(_linear_to_srgb(_srgb_to_linear(clean) * falloff), 0, 1) * 255) / 255
        pairs.append(tuple(torch.from_numpy(x.transpose(2, 0, 1).astype(np.float32)) for x in (clean, captured)))
    return pairs


def _differences(profile, pairs) -> Tensor:
    """Capture minus the profile's deterministic output, ``(N, 3, H, W)``, in levels."""
    simulated = profile.simulate([clean for clean, _ in pairs], 0, deterministic=True)
    return torch.stack([captured - sim for (_, captured), sim in zip(pairs, simulated, strict=True)]) * 255


def _channel_error_levels(profile, pairs) -> np.ndarray:
    """The mean difference per channel over whole frames."""
    return _differences(profile, pairs).mean(dim=(0, 2, 3)).numpy()


def _ring_error_levels(profile, pairs) -> np.ndarray:
    """The mean difference in five rings of the relative radius (0-0.2, ..., 0.8-1)."""
    differences = _differences(profile, pairs).mean(dim=1).numpy()
    size = differences.shape[-1]
    y, x = np.mgrid[:size, :size] - (size - 1) / 2
    radius = np.hypot(y, x) / np.hypot((size - 1) / 2, (size - 1) / 2)
    return np.array([differences[:, (radius >= low) & (radius < low + 0.2)].mean() for low in np.arange(0, 1, 0.2)])


@pytest.mark.slow
def test_a_vignetted_camera_keeps_its_vignetting_and_its_tone() -> None:
    """Before the refit, this fit dropped the vignetting stage (it added more error than it removed: the network
    had learned the frames' mean tone, and the stage, without the exposure its fit solved for, darkened them again)."""
    pairs = _vignetted_pairs()
    lines: list[str] = []
    profile = fit_profile(pairs, RECIPE, log=lines.append)
    assert [type(effect) for effect in profile.effects] == [Vignetting]
    record = profile.fitted["effects"]["vignetting"]
    assert record["kept"] is True and record["chain_tone"] is True and record["relative_mse_gain"] > 0.5
    assert any(line.startswith("effect vignetting:") and line.endswith("refitted through it)") for line in lines)
    # the capture's tone over whole frames: every channel within 1 level, the centre and the corners alike
    assert np.abs(_channel_error_levels(profile, pairs)).max() < 1.0
    rings = _ring_error_levels(profile, pairs)
    assert np.abs(rings).max() < 1.5, rings


def test_the_refit_recovers_an_exposure_the_stages_left_out() -> None:
    """An identity network with a vignetting stage, captures 1.25× as bright in linear light through that same
    vignetting: the refitted curve brightens by the missing exposure, and the error all but vanishes."""
    generator = torch.Generator().manual_seed(0)
    cleans = [torch.rand(3, 32, 32, generator=generator) * 0.7 for _ in range(3)]
    stages = [Vignetting(k1=-0.4), Resolution(0.5)]
    brighter = Vignetting(k1=-0.4)
    captures = []
    for clean in cleans:
        linear = ((clean + 0.055) / 1.055) ** 2.4
        bright = (1.055 * (linear * 1.25).clamp(0, 1) ** (1 / 2.4) - 0.055).clamp(0, 1)
        captures.append(stages[1](brighter(bright[None]))[0].clamp(0, 1))
    network = LocalAffineNet(width=8, curves=True)
    inputs = chain_tone.curve_inputs(network, list(zip(cleans, captures, strict=True)))
    before = chain_tone.chain_error(inputs, network.curve[1], stages)
    knots = chain_tone.refit_output_curve(network.curve[1], inputs, stages)
    assert chain_tone.chain_error(inputs, knots, stages) < 0.05 * before
    assert (knots[:, 4:12] > network.curve[1][:, 4:12]).all()  # mid-tones brighter
    same = chain_tone.refit_output_curve(network.curve[1], inputs, stages)
    assert torch.equal(knots, same)  # deterministic


def test_only_a_network_with_an_output_curve_has_one_to_refit() -> None:
    assert not chain_tone.has_output_curve(LocalAffineNet(width=8, curves=False))
    assert not chain_tone.has_output_curve(None)
    assert chain_tone.has_output_curve(LocalAffineNet(width=8, curves=True))


def test_without_an_output_curve_nothing_is_refitted() -> None:
    profile = CameraProfile(LocalAffineNet(width=8), [Vignetting(k1=-0.3)])
    assert retoned(None, profile) == (None, "the network has no output curve")  # decided before any pair is read


@pytest.mark.slow
def test_a_camera_without_vignetting_gets_no_vignetting_stage() -> None:
    """The stage is judged against the profile with the curve refitted without it: the refit's own gain is not the
    stage's."""
    profile = fit_profile(_vignetted_pairs(corner_degrees=0.0), RECIPE)
    assert list(profile.effects) == []
    assert profile.fitted["effects"]["vignetting"]["kept"] is False


def test_the_refit_reads_at_most_four_mpixels_of_whole_frames() -> None:
    small = [(torch.zeros(3, 128, 128), torch.zeros(3, 128, 128))] * 64
    large = [(torch.zeros(3, 1024, 2048), torch.zeros(3, 1024, 2048))] * 5
    huge = [(torch.zeros(3, 3000, 4000), torch.zeros(3, 3000, 4000))] * 3
    assert len(chain_tone.refit_pairs(small, 32)) == 32
    assert len(chain_tone.refit_pairs(large, 32)) == 2
    assert len(chain_tone.refit_pairs(huge, 32)) == 1
