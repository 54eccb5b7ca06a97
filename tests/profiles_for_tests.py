"""Small profiles built in memory for tests: one deterministic, one with a stochastic stage."""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import Tensor

from camdegrade import CameraProfile, DomainShiftNet
from camdegrade.effects import EFFECTS, Effect, register_effect


def seeded_network(seed: int = 0) -> DomainShiftNet:
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        return DomainShiftNet()


class AdditiveTestNoise(Effect):
    """A minimal stochastic stage (Gaussian noise of a stored std) used to test the profile plumbing."""

    name = "test_additive_noise"
    stage = "sensor"

    def __init__(self, std: float = 0.05) -> None:
        super().__init__()
        self.register_buffer("std", torch.tensor(float(std)))

    def make_params(self, shape, generator=None) -> dict[str, Tensor]:
        return {"normal": torch.randn(tuple(shape), generator=generator)}

    def forward(self, image: Tensor, params: Mapping[str, Tensor] | None = None) -> Tensor:
        normal = (params or self.make_params(image.shape))["normal"]
        return (image + self.std * normal).clamp(0, 1)


if AdditiveTestNoise.name not in EFFECTS:
    register_effect(AdditiveTestNoise)


def deterministic_profile() -> CameraProfile:
    return CameraProfile(seeded_network(), name="test-deterministic", description="network only")


def stochastic_profile() -> CameraProfile:
    return CameraProfile(seeded_network(), [AdditiveTestNoise(0.05)], name="test-stochastic")
