"""The sharpen stage: its kernel (halos, coring, luma), its values, and its fitter's stated recovery tolerance."""

from __future__ import annotations

import pytest
import torch
from torch import Tensor

from camdegrade.effects import Blur, Sharpen
from camdegrade.functional import unsharp_mask_image
from camdegrade.functional.isp.sharpen import coring
from effects_images import photo_batch, photos_for_fitting


def _step(low: float = 0.3, high: float = 0.7, size: int = 32) -> Tensor:
    """A vertical step edge, ``(1, 3, size, size)``."""
    image = torch.full((1, 3, size, size), low)
    image[..., size // 2 :] = high
    return image


def test_coring_passes_large_detail_and_zeroes_small_detail() -> None:
    detail = torch.tensor([0.001, 0.01, 0.1, -0.1])
    cored = coring(detail, torch.tensor(0.01))
    assert float(cored[0]) < 0.01 * 0.001  # a tenth of the threshold: 1 % of it passes
    assert float(cored[1]) == pytest.approx(0.005)  # half at the threshold
    assert float(cored[2]) == pytest.approx(0.1 / 1.01) and float(cored[3]) == pytest.approx(-0.1 / 1.01)
    torch.testing.assert_close(coring(detail, torch.tensor(0.0)), detail, rtol=1e-6, atol=0)


def test_unsharp_mask_overshoots_a_step_edge_by_the_amount() -> None:
    step = _step()
    out = unsharp_mask_image(step, 1.0, 1.0)
    row = out[0, 0, 16]
    # The sampled Gaussian (centre tap w0) takes 0.4 · (1 − w0) / 2 off the first bright pixel; amount 1 adds it
    # back above 0.7 (and as much below 0.3 on the first dark one).
    centre = 1.0 / float(torch.exp(-0.5 * torch.arange(-4.0, 5.0) ** 2).sum())
    overshoot = 0.4 * (1.0 - centre) / 2
    assert float(row.max()) == pytest.approx(0.7 + overshoot, abs=1e-5)
    assert float(row.min()) == pytest.approx(0.3 - overshoot, abs=1e-5)
    far = torch.cat([row[:8] - 0.3, row[-8:] - 0.7])  # the halo is gone 8 px from the edge
    assert float(far.abs().max()) < 1e-6
    twice = unsharp_mask_image(step, 1.0, 2.0)[0, 0, 16]
    assert float(twice.max() - 0.7) == pytest.approx(2 * float(row.max() - 0.7), rel=1e-4)


def test_luma_sharpening_adds_the_same_detail_to_every_channel() -> None:
    image = photo_batch() * 0.5 + 0.25  # no clipping
    for luma in (True, False):
        change = unsharp_mask_image(image, 1.5, 0.5, luma=luma) - image
        spread = (change - change.mean(-3, keepdim=True)).abs().max()
        assert (float(spread) < 1e-6) == luma, luma
        assert float(change.abs().max()) > 0.02


def test_coring_keeps_noise_from_being_amplified() -> None:
    noise = 0.004 * torch.randn(1, 3, 64, 64, generator=torch.Generator().manual_seed(0))
    flat = (0.5 + noise).expand(1, 3, 64, 64).contiguous()
    plain = unsharp_mask_image(flat, 1.0, 1.5)
    cored = unsharp_mask_image(flat, 1.0, 1.5, 0.03)
    assert float(plain.std()) > 1.5 * float(flat.std())
    assert float(cored.std()) < 1.05 * float(flat.std())
    edge = _step()
    assert float(unsharp_mask_image(edge, 1.0, 1.5, 0.03).max()) > 0.75  # a 0.4 edge is far above the threshold


def test_kernel_and_constructor_errors_name_the_argument() -> None:
    with pytest.raises(ValueError, match=r"threshold must be non-negative, got threshold=-0\.1"):
        unsharp_mask_image(photo_batch(), 1.0, 1.0, -0.1)
    with pytest.raises(ValueError, match="sigma must be non-negative, got sigma=-1"):
        unsharp_mask_image(photo_batch(), -1.0, 1.0)
    with pytest.raises(ValueError, match=r"amount must be from 0 to 8, got amount=-0\.5"):
        Sharpen(1.0, -0.5)
    with pytest.raises(ValueError, match="sigma must be from 0 to 8, got sigma=9"):
        Sharpen(9.0, 1.0)
    with pytest.raises(ValueError, match=r"threshold must be from 0 to 0\.25, got threshold=0\.3"):
        Sharpen(1.0, 1.0, 0.3)
    loaded = Sharpen(1.0, 1.0)
    loaded.amount.fill_(20.0)
    with pytest.raises(ValueError, match="amount must be from 0 to 8, got amount=20"):
        loaded.check_values()


def test_strength_scales_the_amount_only() -> None:
    effect = Sharpen(1.8, 1.2, 0.02)
    half = effect.scaled(0.5)
    assert (float(half.sigma), float(half.amount), float(half.threshold)) == pytest.approx((1.8, 0.6, 0.02))
    assert effect.magnitude() == pytest.approx(1.2) and half.magnitude() == pytest.approx(0.6)
    assert float(effect.scaled(100.0).amount) == Sharpen.MAX_AMOUNT
    assert Sharpen.neutral().magnitude() == 0.0


# --- the fitter -----------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def photos() -> list[Tensor]:
    return photos_for_fitting(128)


def _fit(photos: list[Tensor], targets: list[Tensor], **options: object) -> Sharpen:
    return Sharpen.fit(photos, targets, **{**Sharpen.fit_options(photos), **options})


def _captured(effect: Sharpen | Blur, photos: list[Tensor]) -> list[Tensor]:
    return [effect(photo[None])[0] for photo in photos]


@pytest.mark.parametrize(
    ("sigma", "amount", "threshold"), [(0.8, 0.3, 0.0), (2.0, 1.5, 0.0), (1.2, 1.0, 0.02), (0.8, 1.5, 0.01)]
)
def test_recovery_within_the_stated_tolerance(
    photos: list[Tensor], sigma: float, amount: float, threshold: float
) -> None:
    fitted = _fit(photos, _captured(Sharpen(sigma, amount, threshold), photos))
    assert abs(float(fitted.sigma) - sigma) < 0.15 * sigma, fitted
    assert abs(float(fitted.amount) - amount) < 0.15 * amount, fitted
    assert abs(float(fitted.threshold) - threshold) < 0.01, fitted
    fitted.check_values()


def test_recovery_survives_noise_and_a_tone_and_colour_shift(photos: list[Tensor]) -> None:
    generator = torch.Generator().manual_seed(1)
    gains = torch.tensor([0.9, 1.0, 1.1])[:, None, None]
    targets = [
        (t * gains + 0.03 + 0.01 * torch.randn(t.shape, generator=generator)).clamp(0, 1)
        for t in _captured(Sharpen(1.5, 0.8, 0.01), photos)
    ]
    fitted = _fit(photos, targets)
    assert abs(float(fitted.sigma) - 1.5) < 0.15 * 1.5 and abs(float(fitted.amount) - 0.8) < 0.15 * 0.8, fitted
    assert abs(float(fitted.threshold) - 0.01) < 0.01, fitted


def test_per_channel_recovery(photos: list[Tensor]) -> None:
    fitted = _fit(photos, _captured(Sharpen(1.0, 1.0, luma=False), photos), luma=False)
    assert not fitted.luma and abs(float(fitted.amount) - 1.0) < 0.15 and abs(float(fitted.sigma) - 1.0) < 0.15


def test_no_sharpening_is_found_where_there_is_none(photos: list[Tensor]) -> None:
    """The same image, the image plus white noise, a softer image: amount 0 (the diagnosis fits a sharpen candidate
    on every camera, most of which do not sharpen more than their profile)."""
    generator = torch.Generator().manual_seed(2)
    noisy = [(p + 0.02 * torch.randn(p.shape, generator=generator)).clamp(0, 1) for p in photos]
    for targets in (photos, noisy, _captured(Blur(1.0), photos)):
        assert float(_fit(photos, targets).amount) < 0.05
