"""The virtual camera: presets, replayable captures, and pair folders the trainer can read."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from camdegrade.effects import JPEG, Blur, Noise, Tone, Vignetting
from camdegrade.io import read_image, write_image
from camdegrade.sim import PRESETS, VirtualCamera, simulate_pairs
from effects_images import photo, photo_batch


def _seeded(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def test_presets_include_the_paper_setting_and_a_milder_one() -> None:
    assert {"lowcost-robot", "phone-indoor"} <= set(PRESETS)
    image = photo_batch()
    robot = VirtualCamera.from_preset("lowcost-robot")(image, generator=_seeded(0))
    phone = VirtualCamera.from_preset("phone-indoor")(image, generator=_seeded(0))
    assert (robot - image).pow(2).mean() > (phone - image).pow(2).mean() > 0
    for name in PRESETS:
        assert PRESETS[name].description and 0 < PRESETS[name].scale <= 1


def test_unknown_preset_lists_the_known_ones() -> None:
    with pytest.raises(KeyError, match="unknown preset 'webcam'; known presets: lowcost-robot, lowcost-robot-wild"):
        VirtualCamera.from_preset("webcam")


@pytest.mark.parametrize("dtype", [torch.uint8, torch.float32, torch.float64])
def test_capture_keeps_shape_and_dtype(dtype: torch.dtype) -> None:
    camera = VirtualCamera.from_preset("lowcost-robot")
    image = photo_batch(40, 56)
    image = (image * 255).round().to(dtype) if dtype == torch.uint8 else image.to(dtype)
    before = image.clone()
    out = camera(image, generator=_seeded(1))
    assert out.shape == image.shape and out.dtype == dtype and torch.equal(image, before)
    assert camera(image[0], generator=_seeded(1)).shape == image[0].shape


def test_captures_replay_from_a_seed_or_from_params() -> None:
    camera = VirtualCamera.from_preset("lowcost-robot-wild")
    image = photo_batch()
    first = camera(image, generator=_seeded(3))
    assert torch.equal(first, camera(image, generator=_seeded(3)))
    assert not torch.equal(first, camera(image, generator=_seeded(4)))
    params = camera.make_params(image.shape, _seeded(3))
    assert torch.equal(camera(image, params), first)
    noise_params = params[[effect.name for effect in camera.effects].index("noise")]
    assert noise_params["normal"].shape == (3, 3, 24, 32)  # the sensor runs at half resolution
    # per-shot variation: the same scene three times gives three different exposures
    same = photo_batch()[:1].expand(3, -1, -1, -1)
    means = camera(same, generator=_seeded(5)).mean((1, 2, 3))
    assert means.max() - means.min() > 0.01


def test_stage_order_and_scale_are_validated() -> None:
    with pytest.raises(
        ValueError, match=r"physical stage order optics → sensor → isp → codec, got jpeg \(codec\), blur"
    ):
        VirtualCamera([JPEG(50), Blur(1.0)])
    with pytest.raises(ValueError, match=r"scale must be in \(0, 1\], got scale=1.5"):
        VirtualCamera([Blur(1.0)], scale=1.5)
    with pytest.raises(TypeError, match=r"effects\[0\] must be a camdegrade Effect"):
        VirtualCamera([torch.nn.Identity()])  # type: ignore[list-item]


def test_optics_only_camera_still_loses_resolution() -> None:
    image = photo("chelsea", 64)[None]
    camera = VirtualCamera([Vignetting(0.0)], scale=0.25)
    out = camera(image)
    assert out.shape == image.shape and (out - image).abs().mean() > 0.01
    assert torch.equal(VirtualCamera([Vignetting(0.0)])(image), Vignetting(0.0)(image))


@pytest.fixture
def input_folder(tmp_path: Path) -> Path:
    folder = tmp_path / "input"
    write_image(photo("astronaut", 48), folder / "astronaut.png")
    write_image(photo("coffee", 56), folder / "sub" / "coffee.jpg")
    return folder


def test_simulate_pairs_writes_matching_clean_and_captured(input_folder: Path, tmp_path: Path) -> None:
    out = tmp_path / "pairs"
    captured = simulate_pairs("lowcost-robot", input_folder, out, seed=7)
    assert [path.relative_to(out / "captured").as_posix() for path in captured] == ["astronaut.png", "sub/coffee.png"]
    for path in captured:
        clean = read_image(out / "clean" / path.relative_to(out / "captured"))
        capture = read_image(path)
        assert clean.shape == capture.shape and not torch.equal(clean, capture)
    record = json.loads((out / "simulation.json").read_text())
    assert record["preset"] == "lowcost-robot" and record["seed"] == 7
    assert [stage["name"] for stage in record["camera"]["effects"]][-1] == "jpeg"


def test_simulate_pairs_is_reproducible_per_image(input_folder: Path, tmp_path: Path) -> None:
    first = simulate_pairs("phone-indoor", input_folder, tmp_path / "a", seed=1)
    again = simulate_pairs("phone-indoor", input_folder, tmp_path / "b", seed=1)
    other = simulate_pairs("phone-indoor", input_folder, tmp_path / "c", seed=2)
    alone = simulate_pairs("phone-indoor", input_folder / "astronaut.png", tmp_path / "d", seed=1)
    assert [p.read_bytes() for p in first] == [p.read_bytes() for p in again]
    assert first[0].read_bytes() != other[0].read_bytes()
    assert alone[0].read_bytes() == first[0].read_bytes()  # seeded by name, not by position in the folder


def test_simulate_pairs_feeds_pair_discovery_and_the_fitters(input_folder: Path, tmp_path: Path) -> None:
    pairs_module = pytest.importorskip("camdegrade.pairs.discovery")
    out = tmp_path / "pairs"
    simulate_pairs(VirtualCamera([JPEG(45)], name="jpeg-only"), input_folder, out)
    report = pairs_module.discover_pairs(out)
    assert len(report.pairs) == 2
    sources = [read_image(pair.clean).float() / 255 for pair in report.pairs]
    targets = [read_image(pair.captured).float() / 255 for pair in report.pairs]
    assert abs(int(JPEG.fit(sources, targets).quality) - 45) <= 5


def test_simulate_pairs_errors(tmp_path: Path, input_folder: Path) -> None:
    with pytest.raises(FileNotFoundError, match="does not exist"):
        simulate_pairs("phone-indoor", tmp_path / "missing", tmp_path / "out")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="holds no images"):
        simulate_pairs("phone-indoor", tmp_path / "empty", tmp_path / "out")
    write_image(photo("astronaut", 32), input_folder / "astronaut.jpg")
    with pytest.raises(ValueError, match=r"would both be written as 'astronaut\.png'"):
        simulate_pairs("phone-indoor", input_folder, tmp_path / "out")
    with pytest.raises(KeyError, match="unknown preset"):
        simulate_pairs("nope", input_folder, tmp_path / "out")
    with pytest.raises(ValueError, match=r"out_dir .* is inside the input folder .*overwrite=True"):
        simulate_pairs("phone-indoor", input_folder, input_folder / "pairs")


def test_virtual_camera_pairs_give_back_known_parameters() -> None:
    sources = [photo(name, 96) for name in ("astronaut", "coffee")]
    camera = VirtualCamera([Vignetting(-0.3), Noise(0.004, 2e-5), Tone(1.2, 0.02, 0.95)])
    targets = [camera(src, generator=_seeded(i)) for i, src in enumerate(sources)]
    assert abs(float(Tone.fit(sources, targets).gamma) - 1.2) < 0.12
