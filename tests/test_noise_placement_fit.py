"""Issue 42, item 2: where a fit's noise stage goes relative to its resampler. Cameras built from numpy and PIL parts
(``tests/foreign_cameras``: PIL box sensor of half the pixels, PIL bicubic 2× upscale, numpy noise), not from our
kernels; the profile holds the resolution stage a fit would find (½). Noise drawn after the upscale is put after the
resolution stage, noise drawn at the sensor before it, and a camera without noise gets none."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from camdegrade import CameraProfile
from camdegrade.effects import Noise, Resolution
from camdegrade.fitting.steps.effects import EffectStage
from foreign_cameras import Camera, scenes
from foreign_cameras.stages import Quantize, SensorSampling, WhiteNoise, Zoom
from steps_for_tests import run_step

torch.set_num_threads(1)


def _camera(before: float, after: float) -> Camera:
    """A sensor of half the pixels (PIL box), white noise of ``before`` (full scale) there, 8 bits, PIL bicubic 2×
    upscale, white noise of ``after``, 8 bits."""
    sensor = (SensorSampling(0.5, "box"), *([WhiteNoise(before)] if before else []), Quantize(8), Zoom("bicubic"))
    return Camera("placement", (*sensor, *([WhiteNoise(after)] if after else []), Quantize(8)))


def _pairs(chain: Camera, count: int, seed: int) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """Walls, photo crops and dead leaves of 96² (:func:`foreign_cameras.scenes`) and their captures, as unit floats."""
    out = []
    for index, clean in enumerate(scenes(count, 96, seed=seed)):
        captured = chain(clean, seed=(seed, index))
        out.append(
            tuple(torch.from_numpy(np.ascontiguousarray(x.transpose(2, 0, 1))).float() / 255 for x in (clean, captured))
        )
    return out


def _noise_step(chain: Camera) -> tuple[CameraProfile, dict]:
    profile = CameraProfile(None, [Resolution(0.5)])
    return run_step(EffectStage(Noise), profile, _pairs(chain, 12, 5), _pairs(chain, 8, 6))


@pytest.mark.slow
def test_noise_after_the_upscale_goes_after_the_resolution_stage() -> None:
    profile, record = _noise_step(_camera(0.0, 0.012))
    assert record["kept"] is True and record["place"] == "after resolution"
    assert [effect.name for effect in profile.effects] == ["resolution", "noise"]
    places = record["places"]
    assert places["after resolution"]["distance"] < places["at its stage"]["distance"]
    assert record["correlation_capture"] < 0.2  # white noise after the upscale


@pytest.mark.slow
def test_noise_at_the_sensor_stays_before_the_resolution_stage() -> None:
    profile, record = _noise_step(_camera(0.012, 0.0))
    assert record["kept"] is True and record["place"] == "at its stage"
    assert [effect.name for effect in profile.effects] == ["noise", "resolution"]
    assert record["correlation_capture"] > 0.4  # upsampled with the image


@pytest.mark.slow
def test_a_camera_without_noise_gets_no_noise_stage() -> None:
    profile, record = _noise_step(_camera(0.0, 0.0))
    assert record["kept"] is False and record["present"] is False
    assert [effect.name for effect in profile.effects] == ["resolution"]
