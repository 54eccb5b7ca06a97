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


# -- the bench's own parts (bench/noise_gap_rows.py, bench/noise_gap_denoiser.py), on synthetic images -------------


def test_the_poisson_gaussian_row_recovers_a_known_line() -> None:
    """Stripes at the eight bin centres with ``var = a·x + b`` noise: the fit gives back ``a`` and ``b``."""
    from conftest import load_script

    rows = load_script("bench/noise_gap_rows.py", "camdegrade_noise_gap_rows")
    a, b = 2e-4, 2e-5  # no clipping at either end (clipped pixels are left out, which would bias the top bin)
    levels = (torch.arange(8) + 0.5) / 8
    clean = levels.repeat_interleave(64)[None, None].expand(3, 160, 512).contiguous()
    generator = torch.Generator().manual_seed(0)
    noisy = clean + (a * clean + b).sqrt() * torch.randn(clean.shape, generator=generator)
    fitted = rows.fit_poisson_gaussian(rows.residual_sums([clean], [noisy.clamp(0, 1)]))
    assert fitted.linear is False
    assert torch.allclose(fitted.a, torch.full((3,), a), rtol=0.1)
    assert torch.allclose(fitted.b, torch.full((3,), b), rtol=0.25)


def test_polyu_scenes_drop_the_crop_number_whatever_the_underscores() -> None:
    from conftest import load_script

    rows = load_script("bench/noise_gap_rows.py", "camdegrade_noise_gap_rows")
    path = "polyu_real_noise/CroppedImages/NikonD800_6-3_125_5000_plant__4_mean.JPG"
    assert rows.scene_of("polyu_real_noise", path) == "NikonD800_6-3_125_5000_plant"
    assert rows.scene_of("polyu_real_noise", path.replace("__4", "_12")) == "NikonD800_6-3_125_5000_plant"
    assert rows.scene_of("sidd_samples", "sidd_samples/GT/GT_3.png") == "GT_3"
    assert rows.held_out("cc15_nam_real_noise", {f"x_{i}" for i in range(6)}) == {"x_1", "x_4"}


def test_the_denoiser_starts_as_the_identity_and_trains_the_same_for_a_seed() -> None:
    from conftest import load_script

    module = load_script("bench/noise_gap_denoiser.py", "camdegrade_noise_gap_denoiser")
    config = module.Denoiser(layers=3, channels=8, steps=10, batch=4, patch=16, warmup=5)
    generator = torch.Generator().manual_seed(0)
    noisy = torch.rand(1, 3, 15, 17, generator=generator)
    assert torch.equal(module.denoise(module.make_denoiser(config, 0), noisy, config.fold), noisy)
    cleans = [torch.full((3, 32, 32), 0.5)]
    noisies = [(cleans[0] + 0.05 * torch.randn(3, 32, 32, generator=generator)).clamp(0, 1)]
    first, second, other = (module.train_denoiser(cleans, noisies, config, seed) for seed in (1, 1, 2))
    weights = [[p.detach() for p in model.parameters()] for model in (first, second, other)]
    assert all(torch.equal(p, q) for p, q in zip(weights[0], weights[1], strict=True))
    assert not torch.equal(weights[0][-2], weights[2][-2])
    assert not torch.equal(module.denoise(first, noisy, config.fold), noisy)
