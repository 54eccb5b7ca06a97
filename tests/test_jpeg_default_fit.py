"""Issue 42: the default fit proposes a JPEG stage where the captures hold JPEG's quantisation lattice, keeps it
where it brings the simulation's 8×8 block edges to the captures' on the validation pairs (the noise refitted
through it), and proposes none for a camera without a codec, even one whose upscale lifts the block-edge energy."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest
import torch
import torch.nn.functional as F

from camdegrade import CameraProfile
from camdegrade._support.pixels import bytes_to_unit, unit_to_bytes
from camdegrade.effects import JPEG, Blur, Noise, Resolution
from camdegrade.fitting import DEFAULT_EFFECTS, FitConfig, fit_profile
from camdegrade.fitting.codec_warning import codec_warnings
from camdegrade.fitting.jpeg_evidence import BLOCK_TOLERANCE, block_edge_ratio, noise_through_codec
from camdegrade.fitting.steps.effects import EffectStages
from camdegrade.functional import jpeg_image
from camdegrade.io import read_image
from camdegrade.sim import VirtualCamera
from camdegrade.synthetic import dead_leaves_images
from steps_for_tests import paired_fit, run_step

torch.set_num_threads(1)
NOISE = Noise(a=0.0004, b=1e-5)


def _chart(size: int, seed: int) -> torch.Tensor:
    """2×2 flat grey patches (where the noise is measured), slightly tinted, their edges off the 8×8 grid (3 px
    from it): a chart edge on the grid lifts the block-edge ratio as a codec does (to 1.9 at 8 px, 2.6 at 16 px),
    which drowned the codec's own lift."""
    generator = torch.Generator().manual_seed(seed)
    grey = torch.linspace(0.12, 0.88, 4)[torch.randperm(4, generator=generator)]
    levels = (grey[None] * (0.9 + 0.2 * torch.rand(3, 1, generator=generator))).clamp(0, 1)
    chart = F.interpolate(levels.reshape(1, 3, 2, 2), size=(size, size), mode="nearest")[0]
    return chart.roll((3, 3), dims=(1, 2))


def _pairs(camera: VirtualCamera, count: int, seed: int, size: int = 96) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """Dead leaves and flat charts alternately, captured through ``camera`` and stored as 8-bit values."""
    leaves = dead_leaves_images(count, size, seed=seed)
    cleans = [bytes_to_unit(leaves[i]) if i % 2 else _chart(size, seed * 100 + i) for i in range(count)]
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        return [(clean, bytes_to_unit(unit_to_bytes(camera(clean, generator=generator)))) for clean in cleans]


def _fit_effects(camera: VirtualCamera, profile: CameraProfile) -> tuple[CameraProfile, dict, list[str]]:
    lines: list[str] = []
    fitted, record = run_step(
        EffectStages(names=("noise", "jpeg")), profile, _pairs(camera, 12, 1), _pairs(camera, 6, 2), lines.append
    )
    return fitted, record, lines


def test_block_edge_ratio_reads_jpeg_blocks_and_not_a_2x_upscale() -> None:
    generator = torch.Generator().manual_seed(3)
    noisy = (0.5 + 0.03 * torch.randn(4, 3, 96, 96, generator=generator)).clamp(0, 1)
    upscaled = F.interpolate(noisy[..., ::2, ::2], scale_factor=2, mode="bicubic").clamp(0, 1)
    compressed = bytes_to_unit(jpeg_image(unit_to_bytes(noisy), 40))
    assert abs(block_edge_ratio(list(noisy)) - 1.0) < 0.03
    assert abs(block_edge_ratio(list(upscaled)) - 1.0) < 0.03  # every second gradient is larger: not a grid
    assert block_edge_ratio(list(compressed)) > 1.5


def test_jpeg_is_a_default_effect_candidate() -> None:
    assert "jpeg" in DEFAULT_EFFECTS and DEFAULT_EFFECTS[:2] == ("noise", "vignetting")


def test_a_camera_with_jpeg_blocks_keeps_a_jpeg_stage_last_and_its_noise_refitted_through_it() -> None:
    camera = VirtualCamera([Blur(0.7), NOISE, JPEG(40)])
    profile, record, lines = _fit_effects(camera, CameraProfile(None, [Blur(0.7)]))
    note = record["jpeg"]
    assert profile.effect_names == ["blur", "noise", "jpeg"], lines
    assert note["kept"] is True and abs(note["quality"] - 40) <= 5, note
    # the proposal's rule: more captures than clean images on the lattice (a noiseless chart whose step edge
    # crosses a block is an exact pattern the lattice reader may take for one; 3 of the 6 clean images here)
    assert note["captures_on_lattice"] == note["captures_telling"] == 6 and note["cleans_on_lattice"] < 6
    left = abs(note["block_edges_real"] - note["block_edges_with"])
    assert left < min(BLOCK_TOLERANCE, abs(note["block_edges_real"] - note["block_edges_without"])), note
    assert "noise_refitted" in note, note  # refitted through the codec, or kept where the refit is no closer
    assert any(line.startswith("effect noise: ") and "flat-noise ratio" in line for line in lines), lines


@pytest.mark.slow
def test_noise_placed_after_a_resampler_is_refitted_through_the_codec_where_it_sits() -> None:
    # a camera whose noise comes after its resize (white), fitted with too little noise there: the refit through the
    # codec must stay after the resampler, where an earlier step placed it, not go back to the sensor stage
    camera = CameraProfile(None, []).with_chain([Resolution(0.5), Noise(a=0.0004, b=1e-5), JPEG(40)])
    profile = CameraProfile(None, []).with_chain([Resolution(0.5), Noise(a=1e-6, b=1e-7), JPEG(40)])
    leaves = dead_leaves_images(12, 96, seed=3)
    cleans = [bytes_to_unit(leaves[i]) if i % 2 else _chart(96, 300 + i) for i in range(12)]
    captures = [bytes_to_unit(unit_to_bytes(image)) for image in camera.simulate(cleans, 5)]
    pairs = list(zip(cleans, captures, strict=True))
    fit = paired_fit(profile, pairs[:8], pairs[8:])
    line = noise_through_codec(fit)
    assert line is not None and "refitted through the jpeg stage" in line, line
    assert fit.profile.effect_names == ["resolution", "noise", "jpeg"]


def test_a_camera_without_a_codec_gets_no_jpeg_stage_though_its_upscale_lifts_the_block_edges() -> None:
    camera = VirtualCamera([Blur(0.7), NOISE, Resolution(0.5)])
    profile, record, lines = _fit_effects(camera, CameraProfile(None, [Blur(0.7), Resolution(0.5)]))
    note = record["jpeg"]
    assert "jpeg" not in profile.effect_names and note["kept"] is False, note
    assert note["captures_on_lattice"] == 0 and note["captures_telling"] >= 4 and "quality" not in note
    assert note["sensor_period"] == 16 and abs(note["sensor_grid_real"] - note["sensor_grid_sim"]) < 0.05, note
    assert any(line.startswith("effect jpeg: not fitted: 0 of") for line in lines), lines
    assert codec_warnings({"effects": record}) == []


def test_jpeg_at_the_sensors_resolution_before_an_upscale_gets_no_stage_and_a_warning() -> None:
    camera = VirtualCamera([Blur(0.7), NOISE, JPEG(40)], scale=0.5)  # compressed at half size, then enlarged
    profile, record, _ = _fit_effects(camera, CameraProfile(None, [Blur(0.7), Resolution(0.5)]))
    note = record["jpeg"]
    assert "jpeg" not in profile.effect_names and note["captures_on_lattice"] == 0, note
    assert note["sensor_period"] == 16 and note["sensor_grid_real"] > note["sensor_grid_sim"] + 0.1, note
    (warning,) = codec_warnings({"effects": record})
    assert "16 px period" in warning and "before the camera's upscale" in warning


def test_clean_images_as_compressed_as_the_captures_get_no_second_codec() -> None:
    cleans = jpeg_image(torch.stack(dead_leaves_images(8, 96, seed=4)), 50)
    pairs = [(bytes_to_unit(clean), bytes_to_unit(clean)) for clean in cleans]
    profile, record = run_step(EffectStages(names=("jpeg",)), CameraProfile(None, []), pairs[:5], pairs[5:])
    assert profile.effect_names == [] and record["jpeg"]["kept"] is False
    assert "as often" in record["jpeg"]["reason"], record["jpeg"]


def _real_pairs(folder: Path, subset: str, count: int, side: int = 256) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """The first ``count`` pairs of ``subset`` in the real pairs' ``pairs.csv``, centre crops of ``side``² on the
    8×8 grid (a JPEG's blocks stay aligned), in [0, 1]."""
    with (folder / "pairs.csv").open() as handle:
        rows = [row for row in csv.DictReader(handle) if row["subset"] == subset][:count]
    out = []
    for row in rows:
        clean, captured = (read_image(folder / row[key]) for key in ("clean", "captured"))
        top = (min(clean.shape[1], captured.shape[1]) - side) // 16 * 8
        left = (min(clean.shape[2], captured.shape[2]) - side) // 16 * 8
        window = (slice(None), slice(top, top + side), slice(left, left + side))
        out.append((bytes_to_unit(clean[window]), bytes_to_unit(captured[window])))
    return out


@pytest.mark.realdata
@pytest.mark.slow
@pytest.mark.parametrize(
    ("subset", "reason"), [("city100_iPhoneX", "0 of"), ("polyu_real_noise", "the clean images hold the lattice")]
)
def test_real_cameras_without_a_codec_of_their_own_get_no_jpeg_stage(
    real_pairs_dir: Path, subset: str, reason: str
) -> None:
    """City100's registered PNG captures hold no lattice; PolyU's captures are camera JPEGs (quality 75), but so are
    its clean (mean) images: a codec stage would compress them again."""
    pairs = _real_pairs(real_pairs_dir, subset, 10)
    profile, record = run_step(EffectStages(names=("jpeg",)), CameraProfile(None, []), pairs[:6], pairs[6:])
    assert profile.effect_names == [] and record["jpeg"]["kept"] is False, record["jpeg"]
    assert record["jpeg"]["reason"].startswith(reason), record["jpeg"]


@pytest.mark.slow
def test_a_default_fit_of_a_camera_that_compresses_before_its_upscale_warns() -> None:
    camera = VirtualCamera([Blur(0.7), NOISE, JPEG(40)], scale=0.5)
    config = FitConfig.recipe("fast").replace(epochs=1, crop=32, crops_per_pair=2, sensor_scale=0.5, texture="none")
    lines: list[str] = []
    profile = fit_profile(_pairs(camera, 12, 1), config.replace(val_fraction=0.34), log=lines.append)
    assert "jpeg" not in profile.effect_names and "resolution" in profile.effect_names, lines
    assert any("before the camera's upscale" in warning for warning in profile.fitted["warnings"]), lines
