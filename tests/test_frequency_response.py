"""The frequency-response stage: its kernel (a gain per frequency knot on the luma), its fitter (the captures' power
per knot, the 4-pixel lattice never amplified) and the fit's response step (kept only on validation evidence)."""

from __future__ import annotations

import math

import pytest
import torch
from torch import Tensor

from camdegrade import CameraProfile
from camdegrade.diagnose.attribution.attribute import check_candidates
from camdegrade.effects import EFFECTS, FrequencyResponse
from camdegrade.fitting.steps.response import ResponseMatch
from camdegrade.functional import frequency_response_image
from camdegrade.functional.isp.response import MAPS_KEPT, response_map
from effects_images import photo
from steps_for_tests import run_step

KNOTS = 11


def knot_radius(knots: int = KNOTS) -> Tensor:
    frequency = torch.arange(knots, dtype=torch.float64) * 0.5 / (knots - 1)
    return (frequency[:, None] ** 2 + frequency[None, :] ** 2).sqrt()


def camera_response() -> Tensor:
    """A smooth response like a phone's: detail around 0.25 cycles/pixel raised 1.6×, the finest cut to 0.7×; 1 at
    the low frequencies and on the 4-pixel lattice, where the fitter keeps it."""
    radius = knot_radius()
    gains = 1 + 0.6 * torch.exp(-(((radius - 0.25) / 0.08) ** 2)) - 0.3 * torch.sigmoid((radius - 0.45) / 0.03)
    gains[radius < 0.03] = 1.0
    for row in (0, 5, 10):
        for col in (0, 5, 10):
            gains[row, col] = min(float(gains[row, col]), 1.0) if row or col else 1.0
    return gains.float()


def crops(count: int = 9, size: int = 96) -> list[Tensor]:
    """Textured crops of three photographs, their values brought into [0.1, 0.9] (a gain clipped at 0 or 1 would
    add power of its own)."""
    images = [photo(name, 320) for name in ("astronaut", "coffee", "chelsea")]
    out = []
    for index in range(count):
        image = images[index % 3]
        top, left = 40 * (index // 3), 60 * (index // 3)
        out.append(0.1 + 0.8 * image[:, top : top + size, left : left + size])
    return out


def eight_bit(image: Tensor) -> Tensor:
    return (image * 255).round() / 255


def test_ones_are_the_identity_for_float_and_uint8() -> None:
    image = photo("astronaut", 80)
    assert (frequency_response_image(image, torch.ones(KNOTS, KNOTS)) - image).abs().max() < 1e-5
    as_bytes = (image * 255).round().to(torch.uint8)
    out = frequency_response_image(as_bytes, torch.ones(5, 5))
    assert out.dtype == torch.uint8 and torch.equal(out, as_bytes)


def test_a_knot_scales_a_sinusoid_at_its_frequency_and_leaves_the_colour() -> None:
    width, frequency = 200, 0.2  # knot (0, 4) of an 11-knot grid
    x = torch.arange(width, dtype=torch.float32)
    wave = 0.5 + 0.1 * torch.cos(2 * math.pi * frequency * x)
    image = torch.stack([wave.expand(64, width), (wave * 0.8).expand(64, width), (wave * 0.6).expand(64, width)])
    gains = torch.ones(KNOTS, KNOTS)
    gains[0, 4] = 2.0
    out = frequency_response_image(image, gains)
    inner = (slice(None), slice(20, 44), slice(40, 160))  # away from the mirrored borders
    change = (out - image)[inner]
    torch.testing.assert_close(change[0], change[1], atol=1e-5, rtol=0)  # the same change on R, G and B
    luma_wave = (image[inner] * torch.tensor([0.299, 0.587, 0.114])[:, None, None]).sum(0)
    luma_out = (out[inner] * torch.tensor([0.299, 0.587, 0.114])[:, None, None]).sum(0)
    ratio = (luma_out - luma_out.mean()).std() / (luma_wave - luma_wave.mean()).std()
    assert ratio == pytest.approx(2.0, abs=0.05)


def test_the_map_interpolates_between_knots() -> None:
    gains = torch.ones(3, 3)
    gains[0, 1] = 3.0  # (|fy|, |fx|) = (0, 0.25)
    mapped = response_map(gains, 8, 16)  # rfft columns at 0, 1/16, ..., 8/16 cycles/pixel
    assert float(mapped[0, 4]) == pytest.approx(3.0)  # 0.25: on the knot
    assert float(mapped[0, 2]) == pytest.approx(2.0)  # 0.125: halfway to it
    assert float(mapped[0, 8]) == pytest.approx(1.0)  # 0.5
    assert float(mapped[4, 4]) == pytest.approx(1.0)  # (0.5, 0.25): the knot row beyond


def test_the_cached_map_follows_the_gains_and_the_size() -> None:
    """The map is built once per gains tensor and size; changing the gains in place, or another size, is seen."""
    image = photo(long_side=64)
    gains = camera_response()
    first = frequency_response_image(image, gains)
    assert torch.equal(frequency_response_image(image, gains), first)
    assert torch.allclose(frequency_response_image(image, gains.clone()), first, atol=1e-6)
    gains.fill_(1.0)  # in place: the cached map must not survive it
    assert torch.allclose(frequency_response_image(image, gains), image, atol=1e-5)
    gains.data = camera_response() * 1.5  # nor a new .data, nor a write through NumPy
    assert not torch.allclose(frequency_response_image(image, gains), first, atol=1e-3)
    gains.numpy()[:] = camera_response().numpy()
    assert torch.equal(frequency_response_image(image, gains), first)
    with torch.inference_mode():  # inference tensors have no version counter: the key does not need one
        assert torch.equal(frequency_response_image(image, gains.clone()), first)
    for size in range(40, 40 + 2 * MAPS_KEPT + 1, 2):  # more sizes than the cache keeps, then the first again
        smaller = image[..., :size, :size]
        assert torch.allclose(
            frequency_response_image(smaller, gains), frequency_response_image(smaller, gains.clone())
        )
    assert torch.equal(frequency_response_image(image, gains), first)


def test_fit_recovers_a_smooth_response() -> None:
    truth = camera_response()
    sources = crops()
    targets = [frequency_response_image(source, truth) for source in sources]
    fitted = FrequencyResponse.fit(sources, targets)
    assert fitted.knots == KNOTS
    error = (fitted.gains / truth - 1).abs()
    assert float(error.max()) < 0.10, error
    assert float(fitted.gains.max()) > 1.4  # the raise around 0.25 cycles/pixel is found, not smoothed away


def test_fit_of_a_target_that_is_the_source_is_the_identity() -> None:
    sources = crops(6)
    fitted = FrequencyResponse.fit(sources, [source.clone() for source in sources])
    assert float((fitted.gains - 1).abs().max()) < 0.03
    assert fitted.magnitude() < 0.01


def test_fit_never_amplifies_the_lattice_or_the_lowest_frequencies() -> None:
    raised = torch.full((KNOTS, KNOTS), 1.5)
    sources = crops(6)
    fitted = FrequencyResponse.fit(sources, [frequency_response_image(source, raised) for source in sources])
    for row, col in [(0, 5), (5, 0), (5, 5), (0, 10), (10, 0), (10, 10), (5, 10), (10, 5)]:
        assert float(fitted.gains[row, col]) <= 1.0
    assert float(fitted.gains[0, 0]) == 1.0 and float(fitted.gains[3, 3]) > 1.3
    assert bool((fitted.gains[knot_radius() < 0.03] == 1.0).all())


def test_a_radial_response_interpolates_in_log_radius_and_keeps_the_low_frequencies_and_lattice() -> None:
    stage = FrequencyResponse.from_radial([0.04, 0.1, 0.3], [1.0, 2.0, 0.5], knots=21)
    gains = stage.gains.double()
    assert float(gains[0, 4]) == pytest.approx(2.0, rel=1e-5)  # at 0.1 exactly
    share = math.log(0.05 / 0.04) / math.log(0.1 / 0.04)
    assert float(gains[0, 2]) == pytest.approx(2.0**share, rel=1e-5)  # 0.05: between the first two, in log radius
    assert float(gains[20, 20]) == pytest.approx(0.5, rel=1e-5)  # beyond the last: constant
    assert bool((gains[knot_radius(21) < 0.03] == 1.0).all())  # below DETAIL_FROM untouched
    torch.testing.assert_close(gains, gains.T)  # radial: the same along both axes
    raised = FrequencyResponse.from_radial([0.04, 0.2], [1.5, 1.5], knots=21).gains
    assert float(raised[0, 10]) == 1.0 and float(raised[10, 10]) == 1.0 and float(raised[0, 9]) == 1.5  # lattice


@pytest.mark.parametrize(
    ("radii", "gains", "message"),
    [
        ([0.1, 0.05], [1.0, 1.0], "radii must be at least two increasing frequencies"),
        ([0.1], [1.0], "radii must be at least two increasing frequencies"),
        ([0.05, 0.1], [1.0], "radii must be at least two increasing frequencies"),
        ([0.0, 0.1], [1.0, 1.0], "radii must be above 0 cycles/pixel"),
        ([0.05, 0.1], [1.0, 0.0], "gains must be above 0 and at most 8"),
        ([0.05, 0.1], [1.0, 9.0], "gains must be above 0 and at most 8"),
        ([0.05, 0.1], [1.0, math.nan], "gains must be finite"),
        ([0.1, math.inf], [1.0, 1.0], "radii must be finite"),
    ],
)
def test_a_radial_response_refuses_bad_radii_by_name(radii, gains, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        FrequencyResponse.from_radial(radii, gains)


@pytest.mark.parametrize(("radii", "gains", "name"), [(None, [1.0, 1.0], "radii"), ([0.1, 0.2], "abc", "gains")])
def test_a_radial_response_refuses_what_is_not_numbers_by_name(radii, gains, name: str) -> None:
    with pytest.raises(TypeError, match=f"{name} must be a sequence of numbers, got {name}="):
        FrequencyResponse.from_radial(radii, gains)


def test_scaled_moves_the_log_gains_and_magnitude_measures_them() -> None:
    gains = torch.full((5, 5), 2.0)
    stage = FrequencyResponse(gains)
    assert stage.magnitude() == pytest.approx(1.0)
    assert torch.equal(stage.scaled(0).gains, torch.ones(5, 5))
    torch.testing.assert_close(stage.scaled(2).gains, torch.full((5, 5), 4.0))
    torch.testing.assert_close(stage.scaled(1).gains, gains)
    assert FrequencyResponse(knots=7).knots == 7 and FrequencyResponse().config() == {"knots": KNOTS}


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: FrequencyResponse(torch.ones(3, 4)), "gains must be a square (K, K) grid"),
        (lambda: FrequencyResponse(-torch.ones(3, 3)), "gains must be from 0 to 8"),
        (lambda: FrequencyResponse(torch.full((3, 3), math.nan)), "gains must be from 0 to 8"),
        (lambda: FrequencyResponse(knots=1), "knots must be an integer from 2 to 64, got knots=1"),
        (lambda: FrequencyResponse.fit(crops(2), crops(2), knots=65), "knots must be an integer from 2 to 64"),
        (lambda: FrequencyResponse(knots=5.5), "knots must be an integer from 2 to 64, got knots=5.5"),
        (lambda: FrequencyResponse(torch.tensor(2.0)), "gains must be a square (K, K) grid with K from 2 to 64"),
        (lambda: FrequencyResponse(torch.ones(1, 1)), "got shape (1, 1)"),
        (lambda: frequency_response_image(torch.rand(3, 8, 8), torch.ones(4)), "gains must be a square (K, K) grid"),
    ],
)
def test_bad_values_are_refused_by_name(make, message: str) -> None:
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        make()


def test_small_images_and_batches_run() -> None:
    gains = camera_response()
    batch = torch.rand(2, 3, 5, 7, generator=torch.Generator().manual_seed(0))
    out = frequency_response_image(batch, gains)
    assert out.shape == batch.shape and bool(torch.isfinite(out).all())
    torch.testing.assert_close(out[1], frequency_response_image(batch[1], gains))


def test_fit_response_keeps_the_stage_the_camera_has() -> None:
    truth = camera_response()
    pairs = [(source, eight_bit(frequency_response_image(source, truth))) for source in crops(12, 128)]
    notes: list[str] = []
    profile, note = run_step(ResponseMatch(), CameraProfile(None, []), pairs[:6], pairs[6:], notes.append)
    assert note["kept"] is True, note
    assert note["val_band_error_after"] < note["val_band_error_before"] - 0.1
    (stage,) = profile.effects
    assert isinstance(stage, FrequencyResponse)
    # Up to 0.4 cycles/pixel: above it these photos' detail is below the 8-bit rounding's, which pulls the gain to 1.
    inside = knot_radius() <= 0.4
    assert float((stage.gains / truth - 1).abs()[inside].max()) < 0.15
    assert "response:" in notes[0] and "kept" in notes[0]


def test_fit_response_drops_it_where_the_camera_has_none() -> None:
    pairs = [(source, eight_bit(source)) for source in crops(12, 128)]
    profile, note = run_step(ResponseMatch(), CameraProfile(None, []), pairs[:6], pairs[6:], lambda _: None)
    assert note["kept"] is False and not profile.effects


def test_the_diagnosis_does_not_try_it_unasked() -> None:
    assert EFFECTS["frequency_response"] is FrequencyResponse and FrequencyResponse.candidate is False
    assert "frequency_response" not in check_candidates(None) and "sharpen" in check_candidates(None)
    assert check_candidates(["frequency_response"]) == ["frequency_response"]
