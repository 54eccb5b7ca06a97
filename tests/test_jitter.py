"""The jitter stage (:class:`camdegrade.effects.Jitter`): a random local displacement, read from the coherence of a
model's output with the captures, and the fit step that adds it (:mod:`camdegrade.fitting.evidence.jitter_step`)."""

from __future__ import annotations

import math

import pytest
import torch

from camdegrade import CameraProfile
from camdegrade.effects import Blur, Jitter, Noise
from camdegrade.fitting.evidence.jitter_step import JitterMatch
from camdegrade.functional.analysis.coherence import bin_centres, coherence, displacement_sigma
from camdegrade.functional.optics.jitter import displacement_field, field_grid, interpolation_power
from camdegrade.measures.fidelity import band_log2_ratios
from camdegrade.synthetic import dead_leaves_images
from steps_for_tests import run_step

torch.set_num_threads(1)


def _images(count: int, seed: int, side: int = 160) -> list[torch.Tensor]:
    return [0.2 + 0.6 * image.float() / 255 for image in dead_leaves_images(count, side, seed=seed)]


def _camera(images: list[torch.Tensor], *stages, seed: int = 0) -> list[tuple[torch.Tensor, torch.Tensor]]:
    camera = CameraProfile(None, list(stages))
    with torch.no_grad():
        return [
            (
                image,
                camera(image[None], camera.make_params((1, *image.shape), torch.Generator().manual_seed(seed + i)))[0],
            )
            for i, image in enumerate(images)
        ]


def test_the_field_has_the_stated_rms_and_one_seed_gives_one_image() -> None:
    normal = torch.randn(4, 2, *field_grid(256, 256, 8.0), generator=torch.Generator().manual_seed(0))
    field = displacement_field(normal, 0.5, 8.0, (256, 256))
    assert 0.4 < float(field.pow(2).mean().sqrt()) < 0.6
    jitter, image = Jitter(0.5), _images(1, seed=1)[0][None]
    first, second = (jitter(image, jitter.make_params(image.shape, torch.Generator().manual_seed(3))) for _ in range(2))
    assert torch.equal(first, second) and not torch.equal(first, image)
    assert torch.equal(Jitter(0.0)(image), image)


def test_an_exact_gaussian_loss_of_coherence_gives_its_sigma_and_too_little_coherence_gives_none() -> None:
    curve = torch.exp(-2 * math.pi**2 * bin_centres() ** 2 * 0.4**2)
    assert displacement_sigma(torch.ones_like(curve), curve) == pytest.approx(0.4, rel=1e-6)
    assert displacement_sigma(curve, curve) == 0.0
    assert displacement_sigma(torch.ones_like(curve), torch.full_like(curve, 0.5)) is None


@pytest.mark.parametrize("sigma", [0.3, 0.6])
def test_a_displacement_is_read_back_from_the_coherence_and_keeps_the_power_spectrum(sigma: float) -> None:
    """The shift moves detail without blurring it: every band's power within 0.05 log2 (the interpolation's mean
    loss, 0.7 log2 per axis at 0.45 cycles/pixel for 0.6 px, is undone before the shift)."""
    pairs = _camera(_images(6, seed=2, side=256), Jitter(sigma))
    cleans, captures = [clean for clean, _ in pairs], [captured for _, captured in pairs]
    fitted = Jitter.fit(cleans, captures)
    assert abs(float(fitted.sigma) - sigma) < 0.2 * sigma, float(fitted.sigma)
    bands = band_log2_ratios(torch.stack(captures), torch.stack(cleans))
    assert max(abs(value) for value in bands) < 0.05, bands
    assert float(interpolation_power(sigma, torch.tensor([0.45]))) < 0.7


def test_the_centre_is_the_mean_over_the_field() -> None:
    """The average of many jittered copies approaches the Gaussian blur :meth:`Jitter.without_randomness` gives."""
    image, jitter = _images(1, seed=4, side=96)[0][None], Jitter(0.6)
    draws = torch.stack(
        [jitter(image, jitter.make_params(image.shape, torch.Generator().manual_seed(i)))[0] for i in range(64)]
    )
    centre = jitter.without_randomness()
    inner = (slice(None), slice(8, -8), slice(8, -8))
    to_centre = (draws.mean(0) - centre(image)[0])[inner].pow(2).mean()
    to_image = (draws.mean(0) - image[0])[inner].pow(2).mean()
    assert isinstance(centre, Blur) and to_centre < 0.25 * to_image, (float(to_centre), float(to_image))


@pytest.mark.slow
def test_the_step_keeps_a_jitter_where_the_camera_displaces() -> None:
    blur = Blur(0.8, linear=False)
    train, val = _camera(_images(8, seed=5), blur, Jitter(0.5)), _camera(_images(6, seed=6), blur, Jitter(0.5), seed=50)
    notes: list[str] = []
    profile, note = run_step(JitterMatch(), CameraProfile(None, [blur]), train, val, notes.append)
    assert note["kept"] is True and 0.35 < note["sigma"] < 0.65, note
    assert note["val_coherence_distance_after"] < note["val_coherence_distance_before"] - 0.05, note
    assert [effect.name for effect in profile.effects] == ["jitter", "blur"]
    assert notes[0].startswith("jitter: 0.") and notes[0].endswith("-> kept"), notes
    assert note["critic"]["not_easier"] is True and note["critic"]["with"] is not None, note


def test_a_noisy_camera_without_displacement_gets_no_jitter() -> None:
    """The control: noise lowers the captures' coherence too, but the profile's own noise already explains it."""
    blur, noise = Blur(0.8, linear=False), Noise(a=0.002, b=1e-4)
    train, val = _camera(_images(8, seed=7), blur, noise), _camera(_images(6, seed=8), blur, noise, seed=50)
    profile, note = run_step(JitterMatch(), CameraProfile(None, [blur, noise]), train, val)
    assert note["kept"] is False and (note["sigma"] is None or note["sigma"] < 0.1), note
    assert [effect.name for effect in profile.effects] == ["blur", "noise"]
    curve = coherence([c for c, _ in train], [x for _, x in train])
    assert float(curve[-5:].mean()) < 0.9  # the noise does lower the coherence the step must not read as a shift
