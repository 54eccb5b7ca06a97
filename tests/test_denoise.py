"""The denoise stage (ISP coring of the fine detail): its kernel, its values, and its fitter's stated tolerance."""

from __future__ import annotations

import pytest
import torch
from torch import Tensor

from camdegrade.effects import Denoise, Sharpen
from camdegrade.functional import blur_image, denoise_image
from effects_images import photo_batch, photos_for_fitting


def test_faint_detail_is_smoothed_away_and_strong_detail_kept() -> None:
    generator = torch.Generator().manual_seed(0)
    grain = 0.004 * torch.randn(1, 1, 64, 64, generator=generator).expand(1, 3, 64, 64)
    step = torch.full((1, 3, 64, 64), 0.3)
    step[..., 32:] = 0.7
    image = step + grain
    out = denoise_image(image, 1.0, 0.03)
    flat = (slice(None), slice(None), slice(8, 56), slice(4, 24))
    assert float(out[flat].std()) < 0.4 * float(image[flat].std())  # grain of 1 level: mostly gone
    assert float(out[flat].std()) == pytest.approx(float(blur_image(image, 1.0)[flat].std()), rel=0.25)
    across = (out - image)[0, 0, 32, 28:36].abs().max()
    blurred = (blur_image(image, 1.0) - image)[0, 0, 32, 28:36].abs().max()
    assert float(across) < 0.15 * float(blurred)  # the 0.4 edge is far above the threshold: nearly untouched
    torch.testing.assert_close(denoise_image(image, 1.0, 0.0), image)


def test_luma_denoising_changes_every_channel_alike() -> None:
    image = photo_batch() * 0.5 + 0.25
    for luma in (True, False):
        change = denoise_image(image, 1.0, 0.05, luma=luma) - image
        spread = (change - change.mean(-3, keepdim=True)).abs().max()
        assert (float(spread) < 1e-6) == luma, luma
        assert float(change.abs().max()) > 0.01


def test_errors_and_strength() -> None:
    with pytest.raises(ValueError, match=r"threshold must be non-negative, got threshold=-0\.1"):
        denoise_image(photo_batch(), 1.0, -0.1)
    with pytest.raises(ValueError, match=r"threshold must be from 0 to 0\.25, got threshold=0\.3"):
        Denoise(1.0, 0.3)
    with pytest.raises(ValueError, match="sigma must be from 0 to 8, got sigma=9"):
        Denoise(9.0, 0.01)
    effect = Denoise(1.5, 0.02)
    half = effect.scaled(0.5)
    assert (float(half.sigma), float(half.threshold)) == pytest.approx((1.5, 0.01))
    assert effect.magnitude() == pytest.approx(5.1) and Denoise.neutral().magnitude() == 0.0
    assert float(effect.scaled(100.0).threshold) == Denoise.MAX_THRESHOLD


@pytest.fixture(scope="module")
def photos() -> list[Tensor]:
    return photos_for_fitting(128)


def _fit(photos: list[Tensor], targets: list[Tensor]) -> Denoise:
    return Denoise.fit(photos, targets, **Denoise.fit_options(photos))


def _through(effect: Denoise | Sharpen, photos: list[Tensor]) -> list[Tensor]:
    return [effect(photo[None])[0] for photo in photos]


@pytest.mark.parametrize(("sigma", "levels"), [(0.8, 4.0), (1.0, 2.0), (1.5, 8.0)])
def test_recovery_within_the_stated_tolerance(photos: list[Tensor], sigma: float, levels: float) -> None:
    fitted = _fit(photos, _through(Denoise(sigma, levels / 255), photos))
    assert abs(fitted.magnitude() - levels) < 0.2 * levels, fitted
    assert abs(float(fitted.sigma) - sigma) < 0.25 * sigma, fitted


def test_recovery_survives_noise_and_a_colour_shift(photos: list[Tensor]) -> None:
    generator = torch.Generator().manual_seed(1)
    gains = torch.tensor([0.9, 1.0, 1.1])[:, None, None]
    targets = [
        (t * gains + 0.03 + 0.002 * torch.randn(t.shape, generator=generator)).clamp(0, 1)
        for t in _through(Denoise(1.0, 4 / 255), photos)
    ]
    fitted = _fit(photos, targets)
    assert abs(fitted.magnitude() - 4.0) < 0.8 and abs(float(fitted.sigma) - 1.0) < 0.25, fitted


def test_none_is_found_where_there_is_none(photos: list[Tensor]) -> None:
    assert _fit(photos, photos).magnitude() < 0.5
    assert _fit(photos, _through(Sharpen(1.0, 1.0), photos)).magnitude() < 0.5
