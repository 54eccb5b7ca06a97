"""Parameter recovery: pairs made with known parameters → each fitter recovers them within its stated tolerance."""

from __future__ import annotations

import pytest
import torch
from torch import Tensor

from camdegrade.effects import (
    JPEG,
    Blur,
    ChromaticAberration,
    Color,
    Distortion,
    Effect,
    Misalignment,
    Tone,
    Vignetting,
)
from effects_images import patch_chart, photos_for_fitting


def _capture(effect: Effect, sources: list[Tensor], seed: int = 0) -> list[Tensor]:
    generator = torch.Generator().manual_seed(seed)
    return [effect(src[None], effect.make_params((1, *src.shape), generator))[0] for src in sources]


def _relative(estimate: Tensor | float, truth: float) -> float:
    return abs(float(estimate) - truth) / abs(truth)


@pytest.fixture(scope="module")
def photos() -> list[Tensor]:
    return photos_for_fitting(128)


def test_tone_recovery(photos: list[Tensor]) -> None:
    for truth in ((1.4, 0.05, 0.9), (0.8, -0.05, 1.1)):
        fitted = Tone.fit(photos, _capture(Tone(*truth), photos))
        for value, expected in zip((fitted.gamma, fitted.black, fitted.white), truth):
            assert _relative(value, expected) < 0.10, (truth, fitted)


def test_tone_exposure_recovery_with_levels_fixed(photos: list[Tensor]) -> None:
    fitted = Tone.fit(photos, _capture(Tone(exposure=-0.5), photos), fit_exposure=True)
    assert _relative(fitted.exposure, -0.5) < 0.10


def test_color_matrix_and_white_balance_recovery(photos: list[Tensor]) -> None:
    matrix = torch.tensor([[1.1, 0.05, 0.0], [0.02, 0.95, 0.03], [0.0, 0.1, 0.8]])
    fitted = Color.fit(photos, _capture(Color(matrix), photos))
    assert (fitted.matrix - matrix).abs().max() < 0.01
    gains = torch.diag(torch.tensor([1.2, 1.0, 0.8]))
    fitted = Color.fit(photos, _capture(Color(gains), photos), diagonal=True)
    assert (fitted.matrix - gains).abs().max() < 0.01


def test_vignetting_recovery(photos: list[Tensor]) -> None:
    fitted = Vignetting.fit(photos, _capture(Vignetting(-0.4, 0.1), photos))
    assert _relative(fitted.k1, -0.4) < 0.10 and abs(float(fitted.k2) - 0.1) < 0.02
    fitted = Vignetting.fit(photos, _capture(Vignetting(-0.3), photos), degree=1)
    assert _relative(fitted.k1, -0.3) < 0.10 and float(fitted.k2) == 0.0


def test_vignetting_ignores_a_global_exposure_change(photos: list[Tensor]) -> None:
    targets = [t * 0.8 for t in _capture(Vignetting(-0.3), photos)]
    assert _relative(Vignetting.fit(photos, targets, degree=1).k1, -0.3) < 0.10


@pytest.mark.parametrize("quality", [23, 60, 88])
def test_jpeg_quality_recovery(photos: list[Tensor], quality: int) -> None:
    fitted = JPEG.fit(photos, _capture(JPEG(quality), photos))
    assert abs(int(fitted.quality) - quality) <= 5


@pytest.mark.parametrize("sigma", [0.8, 2.0])
def test_blur_sigma_recovery(photos: list[Tensor], sigma: float) -> None:
    fitted = Blur.fit(photos, _capture(Blur(sigma), photos), crop=40, crops_per_image=2, max_sigma=4.0, max_iter=30)
    assert _relative(fitted.sigma_x, sigma) < 0.10 and float(fitted.sigma_y) == float(fitted.sigma_x)


def test_blur_recovery_survives_a_tone_and_colour_shift(photos: list[Tensor]) -> None:
    targets = [t * torch.tensor([0.9, 1.0, 1.1])[:, None, None] + 0.03 for t in _capture(Blur(1.5), photos)]
    fitted = Blur.fit(photos, targets, crop=40, crops_per_image=2, max_sigma=4.0, max_iter=30)
    assert _relative(fitted.sigma_x, 1.5) < 0.10


def test_anisotropic_blur_recovery(photos: list[Tensor]) -> None:
    truth = Blur(2.2, 1.0, 30.0)
    fitted = Blur.fit(
        photos, _capture(truth, photos), anisotropic=True, crop=40, crops_per_image=2, max_sigma=4.0, max_iter=30
    )
    assert _relative(fitted.sigma_x, 2.2) < 0.10 and _relative(fitted.sigma_y, 1.0) < 0.10
    assert abs(float(fitted.angle) - 30.0) < 5.0


def test_distortion_recovery(photos: list[Tensor]) -> None:
    for k1 in (0.1, -0.08):
        fitted = Distortion.fit(photos, _capture(Distortion(k1), photos), max_side=128, max_iter=30)
        assert _relative(fitted.k1, k1) < 0.10


@pytest.mark.parametrize(("red", "blue"), [(0.006, -0.004), (0.002, -0.002)])
def test_chromatic_aberration_recovery(photos: list[Tensor], red: float, blue: float) -> None:
    fitted = ChromaticAberration.fit(photos, _capture(ChromaticAberration(red, blue), photos), max_iter=30)
    assert _relative(fitted.red, red) < 0.10 and _relative(fitted.blue, blue) < 0.10


def test_misalignment_recovery_and_spread(photos: list[Tensor]) -> None:
    truth = Misalignment(1.3, -0.7, 0.5)
    targets = [t * 0.95 + 0.02 for t in _capture(truth, photos)]
    fitted = Misalignment.fit(photos, targets, max_side=128, max_iter=30)
    assert abs(float(fitted.dx) - 1.3) < 0.1 and abs(float(fitted.dy) + 0.7) < 0.1
    assert abs(float(fitted.angle) - 0.5) < 0.05
    assert fitted.shift_std < 0.05


def test_fitters_accept_batches_and_uint8_and_reject_mismatched_pairs() -> None:
    batch = torch.stack([patch_chart(64, seed=seed) for seed in range(2)])
    target = Color(torch.diag(torch.tensor([1.1, 1.0, 0.9])))(batch)
    as_bytes = (target * 255).round().to(torch.uint8)
    fitted = Color.fit((batch * 255).round().to(torch.uint8), as_bytes, diagonal=True)
    assert (fitted.matrix.diagonal() - torch.tensor([1.1, 1.0, 0.9])).abs().max() < 0.02
    with pytest.raises(ValueError, match=r"pair 0: source and target must have the same shape"):
        Color.fit([batch[0]], [batch[0, :, :32]])
    with pytest.raises(ValueError, match="same non-zero number of images, got 2 and 1"):
        Color.fit(batch, batch[:1])
    with pytest.raises(ValueError, match="images must be at least 74 pixels on each side to fit, got 64x64, 64x64"):
        Blur.fit(batch, batch, crop=40, max_sigma=4.0)
