"""Issue 25: a fit whose network does not beat the clean image passed through unchanged keeps its effect stages only
(``NETWORK_MIN_GAIN_DB``), so that it cannot damage pairs whose camera only adds noise; a camera with a real
colour, tone or lens effect keeps its network."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch
import torch.nn.functional as F

from camdegrade import load_profile
from camdegrade.effects import Noise
from camdegrade.fitting import FitConfig, fit_profile, quality
from camdegrade.fitting.steps import network as network_step

RECIPE = FitConfig(epochs=2, crop=32, batch_size=4, crops_per_pair=4, val_fraction=0.34, lr=0.003).replace(
    effects=("noise",)
)


def _pairs(*, noise_only: bool, count: int = 6) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """Smooth clean images (flat enough for the noise fit) and 8-bit captures: the clean image plus white noise of
    4 levels (a camera whose expected capture is the clean image), or half as bright plus that noise."""
    generator = torch.Generator().manual_seed(0)
    pairs = []
    for _ in range(count):
        clean = F.interpolate(torch.rand(1, 3, 4, 4, generator=generator), size=(96, 96), mode="bilinear")[0]
        clean = ((clean * 0.6 + 0.2) * 255).round() / 255
        expected = clean if noise_only else clean * 0.5
        captured = expected + torch.randn(clean.shape, generator=generator) * (4 / 255)
        pairs.append((clean, (captured.clamp(0, 1) * 255).round() / 255))
    return pairs


def test_a_noise_only_camera_gets_no_network(tmp_path: Path) -> None:
    lines: list[str] = []
    profile = fit_profile(_pairs(noise_only=True), RECIPE, log=lines.append)
    note = profile.fitted["network"]
    assert profile.network is None and note["kept"] is False
    limit = network_step.NETWORK_MIN_GAIN_DB
    assert note["gain_db"] < limit and note["baseline_gain_db"] < limit
    assert any(line.startswith("network dropped:") for line in lines)
    assert [type(effect) for effect in profile.effects] == [Noise]
    assert 3.0 < profile.effects[0].magnitude() < 5.5  # the camera's 4 levels, fitted on the clean images themselves
    # the quality block still reports the trained network beside the identity it lost to
    assert math.isfinite(profile.quality["network_psnr_db"]) and profile.quality["identity_psnr_db"] > 30
    loaded = load_profile(profile.save(tmp_path / "noise.safetensors"))
    assert loaded.network is None and loaded.fitted["network"]["kept"] is False


def test_the_threshold_decides(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(network_step, "NETWORK_MIN_GAIN_DB", -math.inf)
    profile = fit_profile(_pairs(noise_only=True), RECIPE.replace(effects=()))
    assert profile.network is not None and profile.fitted["network"]["kept"] is True


def test_a_camera_with_a_tone_change_keeps_its_network() -> None:
    profile = fit_profile(_pairs(noise_only=False), RECIPE.replace(effects=()))
    note = profile.fitted["network"]
    assert profile.network is not None and note["kept"] is True
    assert note["gain_db"] > 3.0


@pytest.mark.slow
def test_without_validation_pairs_the_network_is_kept() -> None:
    profile = fit_profile(_pairs(noise_only=True), RECIPE.replace(effects=(), val_fraction=0.0))
    assert profile.network is not None
    assert profile.fitted["network"] == {"kept": True, "min_gain_db": network_step.NETWORK_MIN_GAIN_DB}


def test_a_dropped_network_is_not_warned_about() -> None:
    # the network is no better than the clean image here, and the profile does not hold it: nothing to warn about
    profile = fit_profile(_pairs(noise_only=True), RECIPE.replace(epochs=1))
    assert quality.quality_warnings(profile.quality)  # the trained network's scores alone would warn
    assert profile.network is None and "warnings" not in profile.fitted
