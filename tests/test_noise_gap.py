"""AKLD (camdegrade.measures.akld), the noise measure of the PSNR-gap bench (bench/bench_noise_gap.py): zero for the
same noise, the analytic divergence of two Gaussians for a known level mismatch, DANet's clamp, the local window,
and typed errors for bad input. Synthetic images only."""

from __future__ import annotations

import math

import pytest
import torch

from camdegrade.measures.akld import RATIO_RANGE, akld, gaussian_window, local_noise_variance


def flat_pair(sigma: float = 0.02, size: int = 48, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """A mid-grey clean image and unit-variance noise (scaled by ``sigma``) to add to it."""
    generator = torch.Generator().manual_seed(seed)
    return torch.full((3, size, size), 0.5), sigma * torch.randn(3, size, size, generator=generator)


def gaussian_kl(ratio: float) -> float:
    """KL(N(0, v) ‖ N(0, 1)) for a variance ratio v."""
    return 0.5 * (ratio - 1 - math.log(ratio))


def test_the_same_noise_scores_zero() -> None:
    clean, noise = flat_pair()
    assert akld(clean + noise, clean + noise, clean) == 0.0


@pytest.mark.parametrize("scale", [2.0, 0.5, 1.5])
def test_a_known_level_mismatch_scores_the_gaussian_divergence(scale: float) -> None:
    clean, noise = flat_pair()
    assert akld(clean + scale * noise, clean + noise, clean) == pytest.approx(gaussian_kl(scale**2), rel=1e-6)


def test_ratios_beyond_ten_are_clamped_as_danet_does() -> None:
    clean, noise = flat_pair()
    assert akld(clean + 4 * noise, clean + noise, clean) == pytest.approx(gaussian_kl(RATIO_RANGE[1]), rel=1e-6)
    assert akld(clean, clean + noise, clean) == pytest.approx(gaussian_kl(RATIO_RANGE[0]), rel=1e-6)


def test_two_draws_of_the_same_noise_score_a_little_above_zero() -> None:
    """Each local variance rests on about 25 pixels: two independent draws disagree by a few hundredths, well
    below the published scores (PNGAN 0.153)."""
    clean, first = flat_pair(seed=0)
    _, second = flat_pair(seed=1)
    assert 0.02 < akld(clean + first, clean + second, clean) < 0.08


def test_the_level_is_compared_pixel_by_pixel_not_pooled() -> None:
    """Noise twice as strong on the left and half on the right has the real pooled variance, and still diverges."""
    clean, noise = flat_pair(size=64)
    scale = torch.ones(1, 1, 64)
    scale[..., :32], scale[..., 32:] = 2.0, 0.5
    skewed = noise * scale * math.sqrt(2 / (4 + 0.25))
    assert float(skewed.pow(2).mean()) == pytest.approx(float(noise.pow(2).mean()), rel=0.05)
    assert akld(clean + skewed, clean + noise, clean) > 0.3


def test_a_batch_a_list_and_uint8_agree() -> None:
    clean, noise = flat_pair()
    simulated, real = (clean + 2 * noise).clamp(0, 1), (clean + noise).clamp(0, 1)
    as_list = akld([simulated, simulated[:, :40]], [real, real[:, :40]], [clean, clean[:, :40]])
    batched = akld(torch.stack([simulated, simulated]), torch.stack([real, real]), torch.stack([clean, clean]))
    assert as_list == pytest.approx(batched, rel=0.05)
    to_bytes = lambda x: (x * 255).round().to(torch.uint8)  # noqa: E731
    in_bytes = akld(to_bytes(simulated), to_bytes(real), to_bytes(clean))
    assert in_bytes == pytest.approx(batched, rel=0.05)


def test_local_variance_is_the_window_mean_of_the_squared_difference() -> None:
    window = gaussian_window()
    assert window.shape == (7, 7) and float(window.sum()) == pytest.approx(1.0)
    assert float(window[3, 3] / window[3, 2]) == pytest.approx(math.exp(1 / (2 * 1.4**2)))
    clean = torch.zeros(3, 16, 16)
    noisy = clean.clone()
    noisy[:, 8, 8] = 0.1
    variance = local_noise_variance(noisy, clean)
    assert variance.shape == (1, 3, 16, 16)
    assert float(variance[0, 0, 8, 8]) == pytest.approx(0.01 * float(window[3, 3]), rel=1e-6)
    assert float(variance[0, 0, 0, 0]) == pytest.approx(1e-10)


def test_bad_input_raises_typed_errors_naming_the_argument() -> None:
    clean, noise = flat_pair(size=16)
    with pytest.raises(TypeError, match="simulated must be a tensor or a sequence"):
        akld(None, clean + noise, clean)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match=r"real\[0\] must be a tensor, got ndarray"):
        akld([clean], [clean.numpy()], [clean])  # type: ignore[list-item]
    with pytest.raises(TypeError, match=r"clean must be a float image in \[0, 1\] or uint8, got dtype torch.int64"):
        akld(clean, clean, clean.long())
    with pytest.raises(ValueError, match=r"real must be an image \[N, 3, H, W\] or \[3, H, W\], got shape \(16, 16\)"):
        akld(clean, clean[0], clean)
    with pytest.raises(ValueError, match="simulated and real must have the same shape"):
        akld(clean, clean[:, :8], clean)
    with pytest.raises(ValueError, match="noisy and clean must have the same shape"):
        akld(clean[:, :8], clean[:, :8], clean)
    with pytest.raises(ValueError, match="as many images each, got 2, 1 and 1"):
        akld([clean, clean], [clean], [clean])
    with pytest.raises(ValueError, match="simulated must hold at least one image"):
        akld([], [], [])
    with pytest.raises(ValueError, match="larger than 3 pixels on each side"):
        akld(clean[:, :3], clean[:, :3], clean[:, :3])
    with pytest.raises(ValueError, match="side must be an odd integer >= 3, got side=4"):
        akld(clean, clean, clean, side=4)
