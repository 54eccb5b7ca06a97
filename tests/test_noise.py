"""The noise stage: its structure (level table, correlated field, mixing, banding), replay and old profiles, and its
fitter on synthetic cameras whose noise is known (recovery within the tolerances ``Noise.fit`` states)."""

from __future__ import annotations

import dataclasses

import pytest
import torch
from torch import Tensor

from camdegrade import CameraProfile, load_profile
from camdegrade.effects import Noise
from camdegrade.effects.sensor._noise_fit import LINE_KEPT, _autocorrelation, _set_banding, _symmetric_taps
from camdegrade.fitting.unpaired.steps.noise import flat_sums
from camdegrade.functional import poisson_gaussian_noise_image
from camdegrade.functional.analysis.images import box_mean, flat_mask, flattest_window, noisy_flat_mask
from camdegrade.functional.analysis.noise import NoiseSums, measure_set
from camdegrade.functional.sensor.noise import correlated_field
from effects_images import patch_chart, photos_for_fitting

LEVELS = torch.tensor([[0.004, 0.008, 0.010, 0.012, 0.012, 0.010, 0.008, 0.006]] * 3)
MIXING = torch.tensor([[1.0, 0.0, 0.0], [0.5, 0.866, 0.0], [0.3, 0.5, 0.812]])


def _taps(r1: float, r2: float) -> Tensor:
    return torch.tensor(_symmetric_taps(r1, r2, 5)).expand(3, 5).clone()


def _camera(**options) -> Noise:
    return Noise(levels=LEVELS, across=_taps(0.55, 0.2), down=_taps(0.4, 0.1), mixing=MIXING, linear=False, **options)


def _sources() -> list[Tensor]:
    """Charts with large flat patches (the fitter only measures where the source is flat) and photos."""
    return [patch_chart(256, patches=4, seed=seed) for seed in range(6)] + photos_for_fitting(192)


def _capture(noise: Noise, sources: list[Tensor], seed: int = 5) -> list[Tensor]:
    generator = torch.Generator().manual_seed(seed)
    return [noise(src[None], noise.make_params((1, *src.shape), generator))[0] for src in sources]


def _sums(images: list[Tensor], sources: list[Tensor]) -> NoiseSums:
    return measure_set(images, sources, [flat_mask(src) for src in sources])


def test_symmetric_taps_reach_the_asked_autocorrelation() -> None:
    for r1, r2 in ((0.55, 0.2), (0.3, 0.0), (0.8, 0.5)):
        kernel = torch.tensor(_symmetric_taps(r1, r2, 5))[None]
        assert float(kernel.norm()) == pytest.approx(1.0)
        assert _autocorrelation(kernel)[:, 0].tolist() == pytest.approx([r1, r2], abs=0.01)


def test_correlated_field_has_unit_variance_and_the_kernels_correlation() -> None:
    normal = torch.randn(2, 3, 132, 132, generator=torch.Generator().manual_seed(0))
    field = correlated_field(normal, _taps(0.55, 0.2), _taps(0.4, 0.1), MIXING)
    assert field.shape == (2, 3, 128, 128)
    assert float(field.var()) == pytest.approx(1.0, abs=0.03)
    assert float((field[..., 1:] * field[..., :-1]).mean()) == pytest.approx(0.55, abs=0.03)
    assert float((field[..., 1:, :] * field[..., :-1, :]).mean()) == pytest.approx(0.4, abs=0.03)
    channels = torch.corrcoef(field.transpose(0, 1).reshape(3, -1))
    assert torch.allclose(channels, MIXING @ MIXING.T, atol=0.03)


def test_structured_noise_replays_and_round_trips_through_a_profile(tmp_path) -> None:
    noise = _camera(column_sigma=torch.tensor([0.0, 0.002, 0.0]), gain_jitter=0.2)
    params = noise.make_params((2, 3, 20, 24), torch.Generator().manual_seed(1))
    assert params["normal"].shape == (2, 3, 24, 28) and params["column_normal"].shape == (2, 3, 1, 24)
    image = torch.rand(2, 3, 20, 24, generator=torch.Generator().manual_seed(2))
    first = noise(image, params)
    assert torch.equal(first, noise(image, params))
    CameraProfile(None, [noise], name="n").save(tmp_path / "n.safetensors")
    loaded = load_profile(tmp_path / "n.safetensors").effects[0]
    assert (
        loaded.config()
        == noise.config()
        == {"linear": False, "gain_jitter": 0.2, "knots": 8, "taps": 5, "columns": True, "mixing": True}
    )
    assert torch.equal(loaded(image, params), first)


def test_white_noise_is_the_poisson_gaussian_kernel_byte_for_byte() -> None:
    """Profiles written before the structure existed (no knots, taps, columns) draw and add the same noise."""
    noise = Noise([0.01, 0.02, 0.005], [1e-4, 0.0, 2e-4], 0.003)
    assert noise.config() == {"linear": True, "gain_jitter": 0.0}
    image = torch.rand(2, 3, 16, 16, generator=torch.Generator().manual_seed(3))
    params = noise.make_params(image.shape, torch.Generator().manual_seed(4))
    expected = poisson_gaussian_noise_image(
        image, noise.a, noise.b, params["normal"], row_sigma=noise.row_sigma, row_normal=params["row_normal"]
    )
    assert torch.allclose(noise(image, params), expected, atol=1e-6)


def test_gradients_flow_through_the_structured_stage() -> None:
    noise = _camera()
    image = torch.rand(1, 3, 12, 12, generator=torch.Generator().manual_seed(5)).mul(0.8).add(0.1)
    image.requires_grad_(True)
    out = noise(image, noise.make_params(image.shape, torch.Generator().manual_seed(6)))
    out.sum().backward()
    assert image.grad is not None and bool(torch.isfinite(image.grad).all())


def test_scaling_multiplies_the_noise_power() -> None:
    noise = _camera(column_sigma=torch.full((3,), 0.002))
    stronger = noise.scaled(4.0)
    assert torch.allclose(stronger.levels, 2 * noise.levels) and torch.allclose(
        stronger.column_sigma, 0.004 * torch.ones(3)
    )
    assert stronger.magnitude() == pytest.approx(2 * noise.magnitude(), rel=1e-5)
    assert torch.equal(stronger.across, noise.across)


def test_fit_recovers_level_correlation_and_no_banding() -> None:
    sources = _sources()
    truth = _camera(column_sigma=torch.zeros(3))
    fitted = Noise.fit(sources, _capture(truth, sources), estimator="residual")
    measured = torch.isfinite(_sums(_capture(truth, sources), sources).std())
    ratio = (fitted.levels / truth.levels)[measured]
    assert (ratio - 1).abs().max() < 0.10, fitted.levels / truth.levels
    assert (_autocorrelation(fitted.across) - _autocorrelation(truth.across)).abs().max() < 0.05
    assert (_autocorrelation(fitted.down) - _autocorrelation(truth.down)).abs().max() < 0.05
    assert (fitted.mixing @ fitted.mixing.T - truth.mixing @ truth.mixing.T).abs().max() < 0.05
    noise_std = float(truth.levels.mean())
    assert float(fitted.row_sigma.max()) < 0.1 * noise_std and float(fitted.column_sigma.max()) < 0.1 * noise_std


def test_fit_finds_banding_where_the_camera_has_it() -> None:
    sources = _sources()
    truth = _camera(row_sigma=0.004, column_sigma=torch.zeros(3))
    fitted = Noise.fit(sources, _capture(truth, sources), estimator="residual")
    assert ((fitted.row_sigma - 0.004).abs() / 0.004).max() < 0.20, fitted.row_sigma
    assert float(fitted.column_sigma.max()) < 0.0004


def test_fit_reproduces_physical_white_noise_through_its_table() -> None:
    """A Poisson–Gaussian sensor in linear light: the fitted table (sRGB values) gives the same noise per bin."""
    sources = _sources()
    truth = Noise(0.004, 2e-5)
    captures = _capture(truth, sources)
    fitted = Noise.fit(sources, captures, estimator="residual")
    real = _sums([c - s + 0.5 for c, s in zip(captures, sources, strict=True)], sources)
    simulated = _sums([c - s + 0.5 for c, s in zip(_capture(fitted, sources, seed=9), sources, strict=True)], sources)
    ratio = simulated.std() / real.std()
    assert (ratio[torch.isfinite(ratio)] - 1).abs().max() < 0.10, ratio
    assert float(_autocorrelation(fitted.across).abs().max()) < 0.05  # white stays white


def test_excess_estimator_adds_only_what_the_source_lacks() -> None:
    """The source already carries noise of std 2 levels, the target 4: the stage adds about sqrt(16 − 4) levels,
    and source plus the stage has the target's noise."""
    charts = [patch_chart(256, patches=4, seed=seed) for seed in range(6)]
    generator = torch.Generator().manual_seed(7)
    sources = [(c + torch.randn(c.shape, generator=generator) * 2 / 255).clamp(0, 1) for c in charts]
    targets = [(c + torch.randn(c.shape, generator=generator) * 4 / 255).clamp(0, 1) for c in charts]
    fitted = Noise.fit(sources, targets, taps=1)
    added = fitted.levels[torch.isfinite(_sums(targets, charts).std())] * 255
    assert float(added.median()) == pytest.approx(12**0.5, rel=0.12)
    simulated = _sums(_capture(fitted, sources), charts).pooled_std()
    assert simulated == pytest.approx(_sums(targets, charts).pooled_std(), rel=0.05)


def test_too_few_flat_pixels_is_a_clear_error() -> None:
    photos = photos_for_fitting(96)
    with pytest.raises(ValueError, match=r"too few flat pixels to measure noise: \d+ pixels where the source is flat"):
        Noise.fit(photos, photos)


def test_flat_mask_is_absolute_and_the_flattest_window_finds_the_flat_area() -> None:
    """The threshold is absolute: a ramp of 1 level per pixel is flat (the local mean takes it out), one of 2 levels
    is not, whatever the rest of the image holds; a flat 96² area in a textured frame is found by the window."""
    textured = torch.rand(3, 160, 160, generator=torch.Generator().manual_seed(0))
    textured[:, 40:136, 48:144] = 0.5
    ramp = (torch.arange(160.0) / 255)[None, None, :].expand(3, 160, 160)
    assert flat_mask(ramp)[8:-8, 8:-8].all() and not flat_mask(2 * ramp).any()
    mask = flat_mask(textured)
    assert mask[60:116, 68:124].all() and not mask[:30].any()
    (rows, cols), share = flattest_window(textured, 64)
    assert rows.stop - rows.start == cols.stop - cols.start == 64
    assert 40 <= rows.start <= 72 and 48 <= cols.start <= 80 and share > 0.5
    (rows, cols), _ = flattest_window(textured, 400)
    assert (rows, cols) == (slice(0, 160), slice(0, 160))


def _half_striped(noise_levels: float, generator: torch.Generator) -> Tensor:
    """A frame flat on its left half and striped on its right, with correlated noise of ``noise_levels`` std (a 3×3
    box of white noise: lag-1 correlation 2/3, like a processed capture's)."""
    scene = torch.full((3, 256, 256), 0.45)
    scene[:, :, 128:] += 0.3 * torch.sin(torch.arange(128.0) / 3)
    white = torch.randn(3, 1, 258, 258, generator=generator)
    noise = torch.nn.functional.avg_pool2d(white, 3, stride=1)[:, 0]
    return (scene + noise / noise.std() * noise_levels / 255).clamp(0, 1)


def test_noisy_flat_mask_reads_strong_correlated_noise_that_flat_mask_loses() -> None:
    """At 20 levels of correlated noise the absolute mask keeps no pixel of the flat half (the noise moves the
    gradient past 1.5 levels); the noise-aware one keeps most of it, and the noise read there is the true level
    (not the calm pixels' lower one), with the stripes still out. At 3 levels the two masks are the same."""
    generator = torch.Generator().manual_seed(0)
    strong = [_half_striped(20.0, generator) for _ in range(3)]
    assert sum(int(flat_mask(image).sum()) for image in strong) < 500
    masks = [noisy_flat_mask(image) for image in strong]
    assert all(int(mask[:, 128:].sum()) == 0 and int(mask[:, :128].sum()) > 12_000 for mask in masks)
    assert flat_sums(strong).pooled_std() == pytest.approx(20.0, rel=0.06)
    weak = _half_striped(3.0, generator)
    assert torch.equal(noisy_flat_mask(weak), flat_mask(weak))
    own = NoiseSums.measure(weak, box_mean(weak, 17), flat_mask(weak))
    assert own.pooled_std() == pytest.approx(3.0, rel=0.06)


def _blotchy(sources: list[Tensor], levels: float, seed: int = 3) -> list[Tensor]:
    """``sources`` plus noise correlated over 9 px both ways (a 9×9 box of white noise): further than the stage's
    5-tap kernel reaches, and the same along rows and columns."""
    generator = torch.Generator().manual_seed(seed)
    out = []
    for src in sources:
        white = torch.randn(3, 1, src.shape[-2] + 8, src.shape[-1] + 8, generator=generator)
        blotches = torch.nn.functional.avg_pool2d(white, 9, stride=1)[:, 0]
        out.append((src + blotches / blotches.std() * levels / 255).clamp(0, 1))
    return out


def test_noisy_flat_mask_does_not_read_fine_texture_as_noise() -> None:
    """Fine stripes (period 8–12 px, up to 20 levels) look flat at σ 4 px, as noise does. Where they fill 70 % of
    the frame, the noise's gradient is still read on the tiles without them, and 2 levels of noise read as 2 (a
    global median read 6–17)."""
    generator = torch.Generator().manual_seed(1)
    columns = torch.arange(180.0)
    for period, amplitude in ((8, 10), (10, 20), (12, 20)):
        images = []
        for _ in range(2):
            scene = torch.full((3, 256, 256), 0.45)
            scene[:, :, :180] += amplitude / 255 * torch.sin(2 * torch.pi * columns / period)
            images.append((scene + 2 * torch.randn(3, 256, 256, generator=generator) / 255).clamp(0, 1))
        assert flat_sums(images).pooled_std() == pytest.approx(2.0, rel=0.1), (period, amplitude)


def _line_sums(rows: float, columns: float, lines: int = 1000) -> NoiseSums:
    """Noise sums whose row and column means have these mean squares (levels²) over ``lines`` lines each, with a
    Gaussian line mean's spread."""
    mean_square = torch.tensor([rows, columns], dtype=torch.float64)[:, None].expand(2, 3)
    number = torch.full((2, 3), float(lines), dtype=torch.float64)
    lines_sums = torch.stack([mean_square * number, 3 * mean_square.pow(2) * number, number], -1)
    return dataclasses.replace(NoiseSums.zeros(), lines=lines_sums)


def test_line_mean_excess_that_rows_and_columns_share_is_not_banding() -> None:
    """Line means beyond the fitted stage's null in rows and columns alike are 2-D noise correlated further than the
    kernel reaches (SIDD's phones: 9–12 levels both ways; drawn as banding, a plaid over the frame). Each direction
    keeps what it has beyond the other: the same excess both ways gives none, rows alone keep theirs."""
    null = _line_sums(1.0, 1.0)
    noise = _camera(row_sigma=torch.zeros(3), column_sigma=torch.zeros(3))
    _set_banding(noise, _line_sums(10.0, 10.0), null)
    assert float(noise.row_sigma.abs().max()) == 0.0 and float(noise.column_sigma.abs().max()) == 0.0
    _set_banding(noise, _line_sums(10.0, 4.0), null)
    expected = ((10.0 - 4.0) / LINE_KEPT) ** 0.5 / 255
    assert torch.allclose(noise.row_sigma, torch.full((3,), expected)), noise.row_sigma
    assert float(noise.column_sigma.abs().max()) == 0.0


def test_row_banding_is_found_under_noise_correlated_beyond_the_kernel() -> None:
    sources = _sources()
    banded = _camera(row_sigma=0.004, column_sigma=torch.zeros(3))
    fitted = Noise.fit(sources, _blotchy(_capture(banded, sources), 4.0), estimator="residual")
    assert ((fitted.row_sigma - 0.004).abs() / 0.004).max() < 0.2, fitted.row_sigma
    assert float(fitted.column_sigma.max()) == 0.0, fitted.column_sigma
