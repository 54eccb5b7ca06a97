"""The pixels the flat-noise statistics rest on (issue 42): flat in every channel, so that an edge between two colours
of the same channel mean (a red door on a blue wall) is not read as noise, and a noiseless simulation of a noisy
camera's walls reads a flat-noise ratio far below 1, as the picture shows."""

from __future__ import annotations

import torch
from torch import Tensor

from camdegrade import CameraProfile
from camdegrade.fitting.steps.noise_evidence import noise_evidence
from camdegrade.functional.analysis.images import flat_mask
from camdegrade.measures.fidelity import measure_fidelity


def _two_colour_wall(size: int = 128) -> Tensor:
    """A blue wall with a red door: the two colours have the same channel mean (0.4), so the mean is flat across
    the door's edge while every channel steps by 0.3–0.4."""
    wall = torch.empty(3, size, size)
    wall[:, :, :] = torch.tensor([0.2, 0.4, 0.6])[:, None, None]
    wall[:, :, size // 2 :] = torch.tensor([0.6, 0.4, 0.2])[:, None, None]
    return wall


def _noisy(image: Tensor, levels: float, seed: int) -> Tensor:
    noise = torch.randn(image.shape, generator=torch.Generator().manual_seed(seed)) * levels / 255
    return ((image + noise).clamp(0, 1) * 255).round() / 255


def test_an_edge_between_colours_of_the_same_mean_is_not_flat() -> None:
    wall = _two_colour_wall()
    mask = flat_mask(wall)
    assert not mask[:, 52:76].any()  # within 12 px of the door's edge: the channels step there
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
