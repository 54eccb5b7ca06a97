"""The pixels the flat-noise statistics rest on (issue 42): no edge in any channel, so that an edge between two colours
of the same channel mean (a red door on a blue wall) is not read as noise, and a noiseless simulation of a noisy
camera's walls reads a flat-noise ratio far below 1, as the picture shows; a smooth colour ramp, however steep in each
channel, keeps its flat pixels (the statistics' high pass removes it)."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F
from torch import Tensor

from camdegrade import CameraProfile
from camdegrade.fitting.steps.noise_evidence import noise_evidence
from camdegrade.functional.analysis.images import CHANNEL_SPREAD, FLAT_LEVELS, flat_mask, gaussian_gradient_magnitude
from camdegrade.functional.analysis.noise import NoiseSums
from camdegrade.measures.fidelity import measure_fidelity


def _two_colour_wall(size: int = 128) -> Tensor:
    """A blue wall with a red door: the two colours have the same channel mean (0.4), so the mean is flat across
    the door's edge while every channel steps by 0.3–0.4."""
    wall = torch.empty(3, size, size)
    wall[:, :, :] = torch.tensor([0.2, 0.4, 0.6])[:, None, None]
    wall[:, :, size // 2 :] = torch.tensor([0.6, 0.4, 0.2])[:, None, None]
    return wall


def _colour_ramp(seed: int, size: int = 48) -> Tensor:
    """A bilinear ramp between four random corner colours of the same channel mean (0.5), in 8 bits: the mean is
    flat while each channel climbs up to 5 levels a pixel."""
    corners = torch.rand(3, 2, 2, generator=torch.Generator().manual_seed(seed))
    corners = corners - corners.mean(0, keepdim=True)
    corners = 0.5 + 0.5 * corners / corners.abs().amax()
    ramp = F.interpolate(corners[None], size=(size, size), mode="bilinear", align_corners=True)[0]
    return (ramp * 255).round() / 255


def _noisy(image: Tensor, levels: float, seed: int) -> Tensor:
    noise = torch.randn(image.shape, generator=torch.Generator().manual_seed(seed)) * levels / 255
    return ((image + noise).clamp(0, 1) * 255).round() / 255


def test_an_edge_between_colours_of_the_same_mean_is_not_flat() -> None:
    wall = _two_colour_wall()
    mask = flat_mask(wall)
    assert not mask[:, 54:74].any()  # within 10 px of the door's edge: the statistics' 17×17 window reaches 8
    assert mask[20:108, 16:40].all() and mask[20:108, 88:112].all()  # the wall and the door themselves are flat


def test_a_noiseless_simulation_of_a_noisy_camera_reads_little_flat_noise() -> None:
    """Captures with 2 levels of white noise, a simulation without any: flat-noise ratio about 0.15 (8-bit rounding
    alone), and the fit's noise evidence finds the noise present. With the channel-mean mask the door's edge made
    both read 15–20 levels: ratio 0.99, noise "not above the profile's"."""
    cleans = [_two_colour_wall() for _ in range(4)]
    captures = [_noisy(clean, 2.0, seed) for seed, clean in enumerate(cleans)]
    report = measure_fidelity(cleans, captures, cleans)
    assert report.noise_ratio is not None and report.noise_ratio < 0.3
    _, evidence = noise_evidence(CameraProfile(None, []), None, cleans, captures, eight_bit=True)
    assert evidence.present
    assert evidence.capture_noise is not None and 1.8 < evidence.capture_noise < 2.2


@pytest.mark.parametrize("seed", range(4))
def test_a_smooth_colour_ramp_keeps_its_flat_pixels_and_a_colour_edge_on_it_does_not(seed: int) -> None:
    """The ramp: every pixel 8 px (the erosion) inside the frame is flat, though some channel climbs more than
    √3 × 1.5 levels a pixel on 6–83 % of it (a bound on each channel's raw gradient kept 0–76 % of these pixels);
    what it leaves in the noise statistics' high pass there is 8-bit rounding. A step of 38 levels up in red and
    down in blue across the middle (the mean flat across it): no flat pixel within 10 px of it, all beyond."""
    ramp = _colour_ramp(seed)
    steepest = gaussian_gradient_magnitude(ramp * 255, 2.0).amax(0)[8:-8, 8:-8]
    assert float((steepest >= CHANNEL_SPREAD * FLAT_LEVELS).float().mean()) > 0.05
    mask = flat_mask(ramp)
    assert mask[8:-8, 8:-8].all() and int(mask.sum()) == 32 * 32
    assert NoiseSums.measure(ramp, ramp, mask).pooled_std() < 0.35
    stepped = ramp.clone()
    stepped[0, :, 24:] += 38 / 255
    stepped[2, :, 24:] -= 38 / 255
    mask = flat_mask(stepped.clamp(0, 1))
    assert not mask[:, 14:34].any()
    assert mask[8:-8, 8:14].all() and mask[8:-8, 34:40].all()
