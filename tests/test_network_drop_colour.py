"""Issue 44: a camera whose only effect is a colour shift smaller than its noise (red ×1.025, blue ×0.975 under 12
levels of noise) gains too little PSNR for its network to be kept, but the shift is the camera's on every capture:
the profile without the network keeps a colour stage, so its simulations have the captures' red/blue balance."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from camdegrade.effects import Color, Noise
from camdegrade.fitting import FitConfig, fit_profile
from camdegrade.fitting.colour_shift import channel_shift

torch.set_num_threads(1)
RECIPE = FitConfig(epochs=2, crop=32, batch_size=4, crops_per_pair=4, val_fraction=0.34, lr=0.003).replace(
    effects=("noise",)
)
GAINS = torch.tensor([1.025, 1.0, 0.975])[:, None, None]


def _pairs(gains: torch.Tensor, count: int = 6) -> list[tuple[torch.Tensor, torch.Tensor]]:
    generator = torch.Generator().manual_seed(0)
    pairs = []
    for _ in range(count):
        clean = F.interpolate(torch.rand(1, 3, 4, 4, generator=generator), size=(96, 96), mode="bilinear")[0]
        clean = ((clean * 0.6 + 0.2) * 255).round() / 255
        captured = clean * gains + torch.randn(clean.shape, generator=generator) * (12 / 255)
        pairs.append((clean, (captured.clamp(0, 1) * 255).round() / 255))
    return pairs


def _red_over_blue(images: list[torch.Tensor]) -> float:
    means = torch.stack([image.double().mean((-2, -1)) for image in images]).mean(0)
    return float(means[0] / means[2])


@pytest.mark.slow  # a 2-epoch fit with its steps: about 5 s of CPU
def test_a_colour_shift_under_the_noise_is_kept_without_the_network() -> None:
    pairs = _pairs(GAINS)
    lines: list[str] = []
    profile = fit_profile(pairs, RECIPE, log=lines.append)
    assert profile.network is None and profile.fitted["network"]["kept"] is False
    assert profile.fitted["effects"]["color"]["kept"] is True, profile.fitted["effects"]
    assert [type(effect) for effect in profile.effects] == [Noise, Color]
    cleans, captures = [clean for clean, _ in pairs], [captured for _, captured in pairs]
    simulated = profile.simulate(cleans, seed=0)
    clean_rb, captured_rb, simulated_rb = (_red_over_blue(images) for images in (cleans, captures, simulated))
    assert captured_rb - clean_rb > 0.04  # the cast: 1.025 / 0.975
    assert abs(simulated_rb - captured_rb) < 0.01, (clean_rb, captured_rb, simulated_rb)
    assert any(line.startswith("colour shift: R +0.025, G -0.001, B -0.026 log ratio") for line in lines), lines


def test_no_shift_is_found_where_there_is_none() -> None:
    shift, error, scenes = channel_shift(_pairs(torch.ones(3, 1, 1)), [str(index) for index in range(6)])
    assert scenes == 6 and bool((shift.abs() < 0.005).all()), (shift, error)  # under MIN_SHIFT: not kept
