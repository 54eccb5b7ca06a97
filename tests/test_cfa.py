"""The colour filter array effect: its kernel (bilinear demosaicing of a Bayer mosaic), its 2×2 phase signature,
and its fit on a foreign camera's mosaic and demosaic (tests/foreign_cameras: no camdegrade code)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from camdegrade.effects import Blur, ColorFilterArray
from camdegrade.functional.isp.color import linear_to_srgb, srgb_to_linear
from camdegrade.functional.sensor.cfa import PATTERNS, bayer_masks, demosaic_image, phase_error
from effects_images import photo


def test_sampled_sites_are_kept_and_flat_colour_stays_flat() -> None:
    image = photo()[None]
    out = demosaic_image(image, "RGGB")
    masks = bayer_masks(*image.shape[-2:], "RGGB").bool()
    assert (srgb_to_linear(out) - srgb_to_linear(image))[0][masks].abs().max() < 1e-5
    flat = torch.tensor([0.2, 0.5, 0.7]).reshape(1, 3, 1, 1).expand(1, 3, 9, 12)
    assert (demosaic_image(flat, "BGGR") - flat).abs().max() < 1e-5
    assert demosaic_image((image * 255).round().byte(), "GRBG").dtype == torch.uint8


def test_a_missing_colour_is_the_mean_of_its_neighbours() -> None:
    """Green at a red site of RGGB: the mean of its 4 edge neighbours (in linear light); red at a blue site: the mean
    of its 4 diagonal ones."""
    linear = torch.rand(1, 3, 6, 6, generator=torch.Generator().manual_seed(0))
    out = srgb_to_linear(demosaic_image(linear_to_srgb(linear), "RGGB"))[0]
    green = linear[0, 1]
    assert torch.allclose(out[1, 2, 2], (green[1, 2] + green[3, 2] + green[2, 1] + green[2, 3]) / 4, atol=1e-5)
    red = linear[0, 0]
    assert torch.allclose(out[0, 3, 3], (red[2, 2] + red[2, 4] + red[4, 2] + red[4, 4]) / 4, atol=1e-5)


def test_the_phase_pattern_tells_a_mosaic_from_a_blur() -> None:
    image = photo(long_side=96)
    mosaic = phase_error(demosaic_image(image[None], "RGGB")[0], image)
    blurred = phase_error(Blur(1.0)(image[None])[0], image)
    assert float(mosaic[0, 0, 0]) < 1e-6 and float(mosaic[2, 1, 1]) < 1e-6  # red and blue where sampled
    assert float(mosaic[1, 0, 1]) < 1e-6 and float(mosaic[1, 1, 0]) < 1e-6  # green on its diagonal
    assert float((blurred - 1).abs().max()) < 0.2


def test_errors_name_the_argument() -> None:
    with pytest.raises(ValueError, match=r"pattern must be one of \('RGGB', 'GRBG', 'GBRG', 'BGGR'\), got"):
        ColorFilterArray("RGBG")
    with pytest.raises(ValueError, match="amount must be from 0 to 2, got amount=3"):
        ColorFilterArray("RGGB", 3.0)
    with pytest.raises(ValueError, match="image must be at least 2x2 pixels, got 1x8"):
        demosaic_image(torch.rand(3, 1, 8))


@pytest.mark.parametrize("pattern", ["RGGB", "GRBG"])
def test_fit_finds_a_foreign_bilinear_demosaic(pattern: str) -> None:
    """A foreign Bayer sensor (its own mosaic and bilinear demosaic, in linear light, no noise) of clean scenes: the
    layout found, the amount 1 within 2 %; on the scenes themselves, nothing."""
    from foreign_cameras import scenes
    from foreign_cameras.demosaic import bilinear
    from foreign_cameras.sensor import mosaic
    from foreign_cameras.tone import linear_to_srgb as foreign_encode
    from foreign_cameras.tone import srgb_to_linear as foreign_decode

    cleans = scenes(4, 64, seed=9)
    targets = [foreign_encode(bilinear(mosaic(foreign_decode(c / 255.0), pattern), pattern)) for c in cleans]
    as_tensor = [
        torch.from_numpy(np.ascontiguousarray(x.transpose(2, 0, 1))).float() for x in (c / 255.0 for c in cleans)
    ]
    fitted = ColorFilterArray.fit(as_tensor, [torch.from_numpy(t.transpose(2, 0, 1).copy()).float() for t in targets])
    assert fitted.pattern == pattern and abs(float(fitted.amount) - 1.0) < 0.02
    assert float(ColorFilterArray.fit(as_tensor, as_tensor).amount) == 0.0
    assert set(PATTERNS) == {"RGGB", "GRBG", "GBRG", "BGGR"}


def test_on_whole_foreign_cameras_the_phase_decides() -> None:
    """Whole foreign cameras (noise, colour, tone; tests/foreign_cameras): the phone's Hamilton–Adams RGGB mosaic is
    found (amount 0.74: an edge-directed demosaic errs less than a bilinear one); the webcam, which has no mosaic but
    is softer than the scenes, gets none (without the phase check it got BGGR at 0.70); the bayer-jpeg camera's GRBG
    mosaic is not seen behind its JPEG 75 (every phase alike, 0.99–1.01)."""
    from foreign_cameras import camera, scenes

    cleans = scenes(8, 96, seed=9)
    sources = [torch.from_numpy(c.transpose(2, 0, 1).copy()).float() / 255 for c in cleans]

    def fitted(name: str) -> ColorFilterArray:
        cam = camera(name)
        captures = [
            torch.from_numpy(cam(c, seed=(9, i)).transpose(2, 0, 1).copy()).float() / 255 for i, c in enumerate(cleans)
        ]
        return ColorFilterArray.fit(sources, captures)

    phone = fitted("phone")
    assert phone.pattern == "RGGB" and 0.6 < float(phone.amount) < 0.9
    assert float(fitted("webcam").amount) == 0.0
    assert float(fitted("bayer-jpeg").amount) == 0.0


def test_the_edge_directed_demosaic_keeps_the_samples_and_agrees_with_an_independent_hamilton_adams() -> None:
    """The edge-directed demosaic keeps each sampled value and a flat colour; on clean scenes it is the
    Hamilton–Adams demosaic of tests/foreign_cameras (written apart, numpy only) within 0.01 levels, and differs
    from the bilinear one by several levels."""
    from foreign_cameras import scenes
    from foreign_cameras.demosaic import hamilton_adams
    from foreign_cameras.sensor import mosaic
    from foreign_cameras.tone import linear_to_srgb as foreign_encode
    from foreign_cameras.tone import srgb_to_linear as foreign_decode

    image = photo()[None]
    out = demosaic_image(image, "GBRG", "edge")
    masks = bayer_masks(*image.shape[-2:], "GBRG").bool()
    assert (srgb_to_linear(out) - srgb_to_linear(image))[0][masks].abs().max() < 1e-5
    flat = torch.tensor([0.2, 0.5, 0.7]).reshape(1, 3, 1, 1).expand(1, 3, 9, 12)
    assert (demosaic_image(flat, "RGGB", "edge") - flat).abs().max() < 1e-5
    for clean in scenes(2, 48, seed=3):
        reference = foreign_encode(hamilton_adams(mosaic(foreign_decode(clean / 255.0), "RGGB"), "RGGB"))
        unit = torch.from_numpy(np.ascontiguousarray(clean.transpose(2, 0, 1))).float() / 255
        ours = demosaic_image(unit[None], "RGGB", "edge")[0].permute(1, 2, 0).double().numpy()
        bilinear = demosaic_image(unit[None], "RGGB")[0].permute(1, 2, 0).double().numpy()
        assert np.abs(ours - reference).max() * 255 < 0.01
        assert np.sqrt(((bilinear - reference) ** 2).mean()) * 255 > 1.0


def test_the_stage_keeps_its_demosaic_and_refuses_an_unknown_one() -> None:
    stage = ColorFilterArray("BGGR", 0.5, "edge")
    again = type(stage).from_config(stage.config())
    assert stage.config() == {"pattern": "BGGR", "demosaic": "edge"} and again.demosaic == "edge"
    image = photo(long_side=48)[None]
    assert not torch.allclose(stage(image), ColorFilterArray("BGGR", 0.5)(image))
    with pytest.raises(ValueError, match=r"demosaic must be one of \('bilinear', 'edge'\), got demosaic='ahd'"):
        ColorFilterArray("RGGB", 0.5, "ahd")
    with pytest.raises(ValueError, match=r"method must be one of \('bilinear', 'edge'\), got method='x'"):
        demosaic_image(image, "RGGB", "x")
