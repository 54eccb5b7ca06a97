"""The resampler step: the resolution stage's upsampling kernel chosen by the grid's phase in the gradient energy
(camdegrade.fitting.steps.resolution, camdegrade.measures.traces.grid_phase)."""

from __future__ import annotations

import pytest
import torch

from camdegrade import CameraProfile
from camdegrade._support.pixels import bytes_to_unit, unit_to_bytes
from camdegrade.effects import Noise, Resolution
from camdegrade.fitting import FitConfig
from camdegrade.fitting.steps.resolution import ResamplerKernel, with_upsampler
from camdegrade.functional.sensor.resolution import UPSAMPLERS
from camdegrade.measures.traces.grid_phase import grid_phase_energy, grid_phase_spread
from camdegrade.synthetic import dead_leaves_images
from steps_for_tests import run_step

torch.set_num_threads(1)


def _noise(count: int, side: int, seed: int) -> list[torch.Tensor]:
    generator = torch.Generator().manual_seed(seed)
    return [(0.5 + 0.05 * torch.randn(3, side, side, generator=generator)).clamp(0, 1) for _ in range(count)]


def test_the_grid_phase_tells_the_kernels_apart_and_reads_one_without_a_grid() -> None:
    flat = grid_phase_energy(_noise(4, 64, 0), 2)
    assert torch.allclose(flat, torch.ones(2, 2, dtype=torch.float64), atol=0.05)
    patterns = {
        kernel: grid_phase_energy([Resolution(0.5, kernel, "area")(image[None])[0] for image in _noise(4, 64, 1)], 2)
        for kernel in ("bicubic", "catmull_rom", "bilinear", "lanczos", "nearest")
    }
    lows = {kernel: float(pattern[0, 0]) for kernel, pattern in patterns.items()}
    # the sample sits at the pair's middle in even columns: 0.35 (Keys a = -0.5) to 0.61 (Lanczos-3), 0 replicated
    assert lows["nearest"] < 0.01 < lows["catmull_rom"] < lows["bilinear"] < lows["bicubic"] < lows["lanczos"] < 0.7
    assert grid_phase_spread(_noise(8, 64, 2), 2) < 0.03 and grid_phase_spread(_noise(1, 64, 2), 2) == float("inf")
    with pytest.raises(ValueError, match="period must be at least 1, got period=0"):
        grid_phase_energy(_noise(1, 8, 0), 0)


def _pairs(camera: CameraProfile, count: int, seed: int) -> list[tuple[torch.Tensor, torch.Tensor]]:
    cleans = [bytes_to_unit(image) for image in dead_leaves_images(count, 64, seed=seed)]
    captures = [bytes_to_unit(unit_to_bytes(image)) for image in camera.simulate(cleans, seed)]
    return list(zip(cleans, captures, strict=True))


@pytest.mark.parametrize("kernel", ["catmull_rom", "lanczos"])
def test_the_step_finds_the_cameras_kernel_and_keeps_scale_and_sampling(kernel: str) -> None:
    noise = Noise(a=0.0003, b=2e-5)
    camera = CameraProfile(None, [noise, Resolution(0.5, kernel, "area")])
    profile = CameraProfile(None, [noise, Resolution(0.5, "bicubic", "area")])
    fitted, record = run_step(ResamplerKernel(), profile, _pairs(camera, 8, 1), _pairs(camera, 8, 2))
    stage = fitted.effects[-1]
    assert record["kept"] is True and record["upsample"] == kernel == stage.upsample, record
    assert float(stage.scale) == 0.5 and stage.sample == "area"
    assert record["distances"][kernel] < record["distances"]["bicubic"] - 3 * record["spread"], record


def test_the_step_keeps_the_kernel_the_camera_used_and_needs_a_resolution_stage() -> None:
    camera = CameraProfile(None, [Noise(a=0.0003, b=2e-5), Resolution(0.5, "bicubic", "area")])
    _, record = run_step(ResamplerKernel(), camera, _pairs(camera, 8, 1), _pairs(camera, 8, 2))
    assert record["kept"] is False and record["upsample"] == "bicubic" and set(record["distances"]) == set(UPSAMPLERS)
    _, none = run_step(ResamplerKernel(), CameraProfile(None, []), _pairs(camera, 2, 1), _pairs(camera, 2, 2))
    assert none == {"kept": False, "reason": "the profile has no resolution stage"}


def test_the_default_recipe_runs_it_after_the_effect_stages() -> None:
    names = [step.name for step in FitConfig.recipe("fast").steps]
    assert names.index("effects") + 1 == names.index("resampler")
    assert "resampler" not in [step.name for step in FitConfig.recipe("paper").steps]
    swapped = with_upsampler(CameraProfile(None, [Resolution(0.5, "bicubic", "area")]), "lanczos").effects[0]
    assert (swapped.upsample, swapped.sample, float(swapped.scale)) == ("lanczos", "area", 0.5)
