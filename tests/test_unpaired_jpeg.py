"""The unpaired fit's codec stage (issue 44), on captures made by parts that are not ours (scikit-image's PNG photos,
PIL's resizes and PIL's JPEG): a set saved at two qualities is modelled as that mixture; images that were never
block-compressed get no jpeg stage however much block-edge energy a resize left; a JPEG saved again as PNG gets its
exact quality from the lattice its pixels hold; clean images compressed as much as the captures get none."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import pytest
import skimage.data
import torch
from PIL import Image

from camdegrade.effects import JPEG
from camdegrade.fitting.unpaired import MIN_IMAGES, fit_unpaired

torch.set_num_threads(1)


def _crops(count: int, side: int, first: int = 0) -> list[Image.Image]:
    """``count`` crops of ``side``² from scikit-image's PNG photos, each at another place (``first`` skips some)."""
    photos = [Image.fromarray(getattr(skimage.data, name)()) for name in ("astronaut", "coffee", "chelsea")]
    out = []
    for index in range(first, first + count):
        photo = photos[index % 3]
        step = index // 3
        left, top = (17 * step) % (photo.width - side), (11 * step) % (photo.height - side)
        out.append(photo.crop((left, top, left + side, top + side)))
    return out


def _save(pictures: list[Image.Image], folder: Path, qualities: list[int | None]) -> Path:
    """Each picture as a JPEG file at its quality, or as a PNG (``None``)."""
    folder.mkdir(parents=True, exist_ok=True)
    for index, (picture, quality) in enumerate(zip(pictures, qualities, strict=True)):
        if quality is None:
            picture.save(folder / f"{index:03d}.png")
        else:
            picture.save(folder / f"{index:03d}.jpg", quality=quality)
    return folder


def _jpeg(profile) -> JPEG | None:
    found = [effect for effect in profile.effects if isinstance(effect, JPEG)]
    return found[0] if found else None


def test_captures_saved_at_two_qualities_are_simulated_at_both(tmp_path: Path) -> None:
    qualities = [30 if index % 2 == 0 else 95 for index in range(10)]
    lines: list[str] = []
    profile = fit_unpaired(_save(_crops(10, 96), tmp_path / "cap", qualities), effects=("jpeg",), log=lines.append)
    stage = _jpeg(profile)
    assert stage is not None and stage.mixture == {30: 0.5, 95: 0.5} and stage.quality_jitter == 0, stage
    assert profile.fitted["effects"]["jpeg"]["images_per_quality"] == {"30": 5, "95": 5}
    assert any(line.startswith("jpeg: qualities 30 (5 images), 95 (5 images) read from 10 files'") for line in lines)
    offsets = stage.make_params((400, 3, 8, 8), torch.Generator().manual_seed(0))["quality_offset"]
    drawn = Counter((stage.quality + offsets).long().tolist())
    assert set(drawn) == {30, 95} and 150 <= drawn[30] <= 250, drawn


@pytest.mark.parametrize("method", [Image.BICUBIC, Image.LANCZOS, Image.BOX])
def test_pngs_upscaled_by_pil_get_no_jpeg_stage(tmp_path: Path, method: int) -> None:
    """A 2× upscale puts 1.09–2.01× the mean gradient energy on the 8×8 block edges (above the 1.08 that used to
    mean JPEG blocks) and no quantisation lattice."""
    upscaled = [crop.resize((192, 192), method) for crop in _crops(MIN_IMAGES, 96)]
    profile = fit_unpaired(_save(upscaled, tmp_path / "cap", [None] * MIN_IMAGES), effects=("jpeg",))
    assert _jpeg(profile) is None and "warnings" not in profile.fitted, profile.fitted["effects"]["jpeg"]
    assert "no JPEG quantisation lattice" in profile.fitted["not_fitted"]["jpeg"]


def test_a_jpeg_saved_again_as_png_gets_its_exact_quality_and_a_warning(tmp_path: Path) -> None:
    folder = _save(_crops(MIN_IMAGES, 96), tmp_path / "jpg", [40] * MIN_IMAGES)
    as_png = _save([Image.open(path) for path in sorted(folder.iterdir())], tmp_path / "png", [None] * MIN_IMAGES)
    profile = fit_unpaired(as_png, effects=("jpeg",))
    stage = _jpeg(profile)
    assert stage is not None and int(stage.quality) == 40 and stage.mixture == {} and stage.probability == 1.0
    assert profile.fitted["effects"]["jpeg"]["read_from"] == "lattice"
    assert len(profile.fitted["warnings"]) == 1 and "quantisation lattice" in profile.fitted["warnings"][0]


def test_clean_images_compressed_as_much_as_the_captures_get_no_stage(tmp_path: Path) -> None:
    captures = _save(_crops(MIN_IMAGES, 96), tmp_path / "cap", [85] * MIN_IMAGES)
    clean = _save(_crops(MIN_IMAGES, 96, first=MIN_IMAGES), tmp_path / "clean", [85] * MIN_IMAGES)
    same = fit_unpaired(captures, clean, effects=("jpeg",))
    assert _jpeg(same) is None, same.fitted["effects"]["jpeg"]
    assert "compressed no more than the clean images" in same.fitted["not_fitted"]["jpeg"]
    better = _save(_crops(MIN_IMAGES, 96, first=MIN_IMAGES), tmp_path / "better", [95] * MIN_IMAGES)
    worse = fit_unpaired(
        _save(_crops(MIN_IMAGES, 96), tmp_path / "worse", [75] * MIN_IMAGES), better, effects=("jpeg",)
    )
    assert _jpeg(worse) is not None and int(_jpeg(worse).quality) == 75


@pytest.mark.realdata
@pytest.mark.slow  # reads 20 of City100's 840×600 PNGs
def test_city100_captures_shrunk_to_256_px_get_no_jpeg_stage(real_pairs_dir: Path, tmp_path: Path) -> None:
    """The REAL City100 iPhone X captures (PNG, registered: resampled) shrunk by PIL: they got a jpeg q30 stage from
    their block-edge energy (1.18× the mean)."""
    folder = real_pairs_dir / "city100_camera_lens_sr" / "City100_iPhoneX"
    shrunk = []
    for scene in range(36, 56):
        with Image.open(folder / f"{scene:03d}L.PNG") as picture:
            shrunk.append(picture.convert("RGB").resize((256, 183), Image.BICUBIC))
    profile = fit_unpaired(_save(shrunk, tmp_path / "cap", [None] * len(shrunk)), effects=("jpeg",))
    assert _jpeg(profile) is None and profile.fitted["effects"]["jpeg"]["uncompressed_images"] == 20


@pytest.mark.slow
def test_pngs_upscaled_by_pil_get_neither_a_jpeg_nor_a_sharpen_stage_by_default(tmp_path: Path) -> None:
    """The red team's 2× upscaled PNGs got jpeg q75 and sharpen 2.0 (the spectrum refit around the false codec)."""
    upscaled = [crop.resize((192, 192), Image.BICUBIC) for crop in _crops(MIN_IMAGES, 96)]
    profile = fit_unpaired(_save(upscaled, tmp_path / "cap", [None] * MIN_IMAGES))
    assert not {"jpeg", "sharpen"} & set(profile.effect_names), profile.effect_names
