"""The captures' codec kept for the noise the chain adds where the clean images are compressed as much (issue 43's
PolyU case: the camera's noise went through its JPEG, the simulated noise through none, and the fit's own
image-only critic told them apart at 0.85; docs/results.md, "The PolyU unpaired self-check: the codec the camera's
noise went through")."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import skimage.data
import torch
from PIL import Image, ImageFilter

from camdegrade.effects import JPEG, Noise
from camdegrade.fitting.unpaired import MIN_IMAGES, fit_unpaired

torch.set_num_threads(1)
SIDE = 96


def _pictures(count: int, first: int, noise: float, seed: int) -> list[Image.Image]:
    """``count`` crops of scikit-image's photos, smoothed (flat regions to read noise on), with white noise of
    ``noise`` levels."""
    photos = [Image.fromarray(getattr(skimage.data, name)()) for name in ("astronaut", "coffee", "chelsea")]
    rng = np.random.default_rng(seed)
    out = []
    for index in range(first, first + count):
        photo = photos[index % 3]
        left, top = (37 * (index // 3)) % (photo.width - SIDE), (29 * (index // 3)) % (photo.height - SIDE)
        crop = photo.crop((left, top, left + SIDE, top + SIDE)).filter(ImageFilter.GaussianBlur(2))
        noisy = np.asarray(crop, np.float64) + rng.normal(0.0, noise, (SIDE, SIDE, 3))
        out.append(Image.fromarray(noisy.round().clip(0, 255).astype(np.uint8)))
    return out


def _save(pictures: list[Image.Image], folder: Path, quality: int) -> Path:
    folder.mkdir(parents=True)
    for index, picture in enumerate(pictures):
        picture.save(folder / f"{index:03d}.jpg", quality=quality)
    return folder


def _high_luma_zeros(image: torch.Tensor) -> float:
    """The share of the luma DCT coefficients at ``u + v ≥ 6`` of the 8×8 blocks under 0.75 in magnitude (levels):
    a JPEG at quality 85 sets nearly all of them to zero in a flat region, noise added after it none."""
    luma = (torch.tensor([0.299, 0.587, 0.114]) @ image.reshape(3, -1)).reshape(image.shape[1:]) * 255
    k = torch.arange(8.0)
    basis = torch.cos(math.pi * (2 * k[None] + 1) * k[:, None] / 16) * math.sqrt(2 / 8)
    basis[0] /= math.sqrt(2)
    blocks = luma.unfold(0, 8, 8).unfold(1, 8, 8).reshape(-1, 8, 8)
    coefficients = basis @ blocks @ basis.T
    high = (k[:, None] + k[None]) >= 6
    return float((coefficients[:, high].abs() < 0.75).float().mean())


def _flat_grey(profile) -> torch.Tensor:
    grey = torch.full((1, 3, 64, 64), 0.5)
    with torch.no_grad():
        return profile(grey, profile.make_params(grey.shape, torch.Generator().manual_seed(0)))[0]


@pytest.mark.slow  # one unpaired fit of noise and codec (about 4 s on one core)
def test_noisy_captures_as_compressed_as_the_clean_images_keep_the_codec_after_the_noise(tmp_path: Path) -> None:
    """Captures with 4 levels of noise saved at q85 beside other scenes saved at q85 without noise: the codec stage is
    kept (it was refused: "compressed no more than the clean images"), after the noise, so a flat grey's simulated
    noise has the captures' zeroed high frequencies; with no noise asked for, it is still refused."""
    captures = _save(_pictures(MIN_IMAGES, 0, 4.0, 0), tmp_path / "cap", 85)
    clean = _save(_pictures(MIN_IMAGES, MIN_IMAGES, 0.0, 1), tmp_path / "clean", 85)
    profile = fit_unpaired(captures, clean, effects=("noise", "jpeg"))
    assert profile.effect_names == ["noise", "jpeg"], profile.fitted["effects"]
    record = profile.fitted["effects"]["jpeg"]
    assert record["kept"] and record["quality"] == 85, record
    assert record["for_the_noise"]["captures_std_levels"] >= 1.1 * record["for_the_noise"]["clean_std_levels"]
    grey = _flat_grey(profile)
    assert grey.std() * 255 > 1.0 and _high_luma_zeros(grey) > 0.9, _high_luma_zeros(grey)
    without_codec = _flat_grey(profile.with_chain([e for e in profile.effects if isinstance(e, Noise)]))
    assert _high_luma_zeros(without_codec) < 0.7
    codec_only = fit_unpaired(captures, clean, effects=("jpeg",))
    assert not any(isinstance(e, JPEG) for e in codec_only.effects), codec_only.fitted["effects"]["jpeg"]
    assert "compressed no more than the clean images" in codec_only.fitted["not_fitted"]["jpeg"]


@pytest.mark.slow
def test_clean_images_noisier_than_the_captures_get_no_codec(tmp_path: Path) -> None:
    """Clean images with 4 levels of noise, captures with none, both at q85: no noise for the chain to add, so the
    codec is refused as before (the captures are compressed no more than the clean images)."""
    captures = _save(_pictures(MIN_IMAGES, 0, 0.0, 0), tmp_path / "cap", 85)
    clean = _save(_pictures(MIN_IMAGES, MIN_IMAGES, 4.0, 1), tmp_path / "clean", 85)
    profile = fit_unpaired(captures, clean, effects=("noise", "jpeg"))
    assert profile.effect_names == [], profile.fitted["effects"]
    assert "compressed no more than the clean images" in profile.fitted["not_fitted"]["jpeg"]
