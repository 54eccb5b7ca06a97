"""The unpaired fit's inputs (issue 44): each is refused before any fitting with a typed error naming the argument,
what was expected and what was received, or accepted as :class:`~camdegrade.CameraDegrade` accepts it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from bad_inputs import good_image, one_line_error, run_cli
from camdegrade.errors import PairsError
from camdegrade.fitting.unpaired import MIN_IMAGES, fit_unpaired
from camdegrade.fitting.unpaired.images import MIN_SIDE, load_images


def _images(count: int = MIN_IMAGES, side: int = 32, seed: int = 0) -> list[torch.Tensor]:
    generator = torch.Generator().manual_seed(seed)
    return [torch.randint(0, 256, (3, side, side), dtype=torch.uint8, generator=generator) for _ in range(count)]


def _folder(folder: Path, count: int = MIN_IMAGES, size: tuple[int, int] = (32, 32), seed: int = 0) -> Path:
    for index in range(count):
        good_image(folder / f"{index:02d}.png", size, seed=seed + index)
    return folder


@pytest.mark.parametrize(("side", "shape"), [("captured", (1, 1)), ("clean", (5, 8))])
def test_images_below_16_pixels_a_side_are_refused_naming_the_side_and_the_size(side: str, shape) -> None:
    tiny = [torch.zeros(3, *shape, dtype=torch.uint8)] * MIN_IMAGES
    sides = {"captured": _images(), "clean": _images(seed=1), side: tiny}
    with pytest.raises(
        ValueError,
        match=rf"{side}\[0\] must be at least {MIN_SIDE}x{MIN_SIDE} pixels, got "
        rf"{shape[0]}x{shape[1]}",
    ):
        fit_unpaired(sides["captured"], sides["clean"])


@pytest.mark.parametrize(("side", "size"), [("captured", (1, 1)), ("clean", (5, 8))])
def test_a_folder_of_tiny_images_is_one_line_naming_the_side_the_file_and_the_size(
    side: str, size: tuple[int, int], tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    folders = {"captured": _folder(tmp_path / "cap"), "clean": _folder(tmp_path / "clean", seed=20)}
    folders[side] = _folder(tmp_path / "tiny", size=size)
    output = tmp_path / "p.safetensors"
    code, _, err = run_cli(
        ["fit", "--unpaired", folders["captured"], "--clean", folders["clean"], "-o", output], capsys
    )
    line = one_line_error(err)
    assert code == 1 and line.startswith(f"camdegrade: error: {side} must hold at least {MIN_IMAGES} usable images")
    assert "00.png: too small: " + f"{size[0]}x{size[1]} pixels" in line and not output.exists()


@pytest.mark.parametrize(
    ("image", "error", "message"),
    [
        (torch.full((3, 32, 32), 200.0), ValueError, r"captured\[2\] must be a float image in \[0, 1\].*got values in"),
        (torch.full((3, 32, 32), float("nan")), ValueError, r"captured\[2\] must be a finite image, got NaN"),
        (torch.zeros(3, 32, 32, dtype=torch.int64), TypeError, r"captured\[2\] must be uint8.*got dtype=torch.int64"),
        ("photo.png", TypeError, r"captured\[2\] must be a \(3, H, W\) tensor, an \(H, W, 3\) numpy array or a PIL"),
        (np.zeros((3, 32, 32), np.uint8), ValueError, r"captured\[2\] must be an \(H, W, 3\) numpy image"),
    ],
    ids=["0-255-floats", "nan", "int64", "a-path-in-a-list", "channels-first-numpy"],
)
def test_a_bad_image_in_a_list_is_refused_before_fitting_naming_it(image, error, message) -> None:
    images = _images()
    images[2] = image
    with pytest.raises(error, match=message):
        fit_unpaired(images)


def test_numpy_arrays_and_pil_images_are_read_as_the_same_tensors_are() -> None:
    images = _images(3)
    as_numpy = [image.permute(1, 2, 0).numpy() for image in images]
    as_float = [array.astype(np.float32) / 255 for array in as_numpy]
    as_pil = [Image.fromarray(array) for array in as_numpy]
    expected = load_images(images, "captured").images
    for source in (as_numpy, as_float, as_pil):
        assert all(torch.equal(a, b) for a, b in zip(load_images(source, "captured").images, expected, strict=True))
    with pytest.raises(TypeError, match=r"captured must be a folder of images or a list of images"):
        fit_unpaired(torch.stack(images))


def test_seed_none_and_max_images_zero_are_refused_by_name() -> None:
    with pytest.raises(TypeError, match=r"seed must be an int, got seed=None"):
        fit_unpaired(_images(), seed=None)
    with pytest.raises(ValueError, match=r"max_images must be an integer >= 1, got max_images=0"):
        fit_unpaired(_images(), max_images=0)
    with pytest.raises(
        ValueError, match=r"sensor_scale must be 'auto' or a number from 0.125 to 1, got sensor_scale=2"
    ):
        fit_unpaired(_images(), sensor_scale=2)


def test_flat_captures_are_refused_before_fitting() -> None:
    flat = [torch.full((3, 32, 32), 128, dtype=torch.uint8)] * 10
    with pytest.raises(PairsError, match=r"captured: the images have no contrast"):
        fit_unpaired(flat, _images())


def test_the_same_folder_on_both_sides_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    folder = _folder(tmp_path / "cap")
    output = tmp_path / "p.safetensors"
    code, _, err = run_cli(["fit", "--unpaired", folder, "--clean", folder, "-o", output], capsys)
    assert code == 1 and "the clean images and the captures are the same images (8 of 8" in one_line_error(err)
    copies = _folder(tmp_path / "copies")  # the same pixels in other files
    with pytest.raises(PairsError, match=r"the same images \(8 of 8 captures"):
        fit_unpaired(folder, copies)
    assert not output.exists()


def test_a_given_sensor_scale_is_the_resolution_stage() -> None:
    profile = fit_unpaired(_images(), effects=("resolution",), sensor_scale=0.5)
    assert profile.effect_names == ["resolution"] and float(profile.effects[0].scale) == 0.5
    assert profile.fitted["effects"]["resolution"]["given"] is True
    assert fit_unpaired(_images(), effects=("resolution",), sensor_scale=1).effect_names == []


def test_a_few_images_on_both_sides_are_a_warning() -> None:
    captures, cleans = _images(), _images(seed=1)
    cleans[:2] = captures[:2]  # 2 of 8: a few shared, not the same set
    profile = fit_unpaired(captures, cleans, effects=("vignetting",))
    assert profile.fitted["warnings"] == [
        "2 captures are also clean images (the same pixels): the clean set is of other scenes"
    ], profile.fitted
