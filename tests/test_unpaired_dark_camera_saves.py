"""Issue 44's dark camera (case "effect 2 (tone): gamma must be from 0 (exclusive) to 16"), on a generated camera
darker than ``tests/test_unpaired_validity.py``'s: its captures are the scenes' values squared (a dark tone curve) at
1 % of their level, plus 2 levels of noise. At commit ``e826a1a`` (the tone curve fitted as levels and gamma alone)
the fit took gamma 20.83 with black −7.39 and exposure 0, and the profile could not be saved; that file's camera at
1 % without the squared curve took gamma 15.1, just inside the stage's 16, and saved. Now the exposure is fitted
first: about −9.5 stops and a gamma near 1."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from camdegrade import load_profile
from camdegrade.fitting.unpaired import fit_unpaired
from camdegrade.profile import check_profile_values
from camdegrade.synthetic import dead_leaves_images


def _dark_camera(folder: Path, count: int = 10, size: int = 128) -> Path:
    folder.mkdir()
    generator = np.random.default_rng(5)
    for index, scene in enumerate(dead_leaves_images(count, size, seed=7)):
        pixels = scene.permute(1, 2, 0).numpy().astype(np.float64)
        pixels[16:56, 16:56] = 60 + 15 * index  # a grey card
        dark = 255 * (pixels / 255) ** 2 * 0.01 + generator.normal(0, 2.0, pixels.shape)
        Image.fromarray(np.clip(np.round(dark), 0, 255).astype(np.uint8)).save(folder / f"{index:02d}.png")
    return folder


@pytest.mark.slow
def test_a_camera_with_a_dark_tone_curve_is_an_exposure_and_its_profile_saves(tmp_path: Path) -> None:
    captured = _dark_camera(tmp_path / "captured")
    clean = tmp_path / "clean"
    clean.mkdir()
    for index, scene in enumerate(dead_leaves_images(10, 128, seed=8)):
        Image.fromarray(scene.permute(1, 2, 0).numpy()).save(clean / f"{index:02d}.png")
    profile = fit_unpaired(captured, clean)
    check_profile_values(profile)
    tone = {effect.name: effect for effect in profile.effects}["tone"]
    assert float(tone.gamma) <= 4.0 and float(tone.exposure) < -6.0, tone
    profile.save(tmp_path / "p.safetensors")
    assert load_profile(tmp_path / "p.safetensors").effect_names == profile.effect_names
