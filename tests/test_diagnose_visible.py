"""What a person sees, named by the diagnosis: the network's 4-pixel grid (not a codec's blocks) and texture too
smooth or too sharp (band power), with blur and sharpening as the changes that mend the texture."""

from __future__ import annotations

import copy
import json

import pytest
import torch

from camdegrade.diagnose import DiagnosisReport, diagnose
from camdegrade.diagnose.where import findings, visible
from camdegrade.effects import JPEG, Blur, Noise, Sharpen
from camdegrade.functional import blur_image
from camdegrade.functional.analysis.images import flat_mask
from camdegrade.measures import BAND_EDGES, StatisticSet, family_gaps
from camdegrade.measures.families.blocks import block_excess
from camdegrade.measures.visible import compare_grid, compare_texture
from camdegrade.profile import CameraProfile, load_profile
from camdegrade.sim import VirtualCamera
from conftest import PAPER_BUILT_IN
from effects_images import photo

torch.set_num_threads(1)


def photo_crops(count: int, seed: int, size: int = 64) -> list[torch.Tensor]:
    """Textured crops of three photos (no flat charts: a flat frame has no texture to compare)."""
    generator = torch.Generator().manual_seed(seed)
    out = []
    for index in range(count):
        full = photo(("astronaut", "coffee", "chelsea")[index % 3], 4 * size)
        top, left = (int(torch.randint(0, side - size + 1, (1,), generator=generator)) for side in full.shape[-2:])
        out.append(full[:, top : top + size, left : left + size].clamp(0, 1))
    return out


def noisy(images: list[torch.Tensor], seed: int, levels: float = 1.0) -> list[torch.Tensor]:
    generator = torch.Generator().manual_seed(seed)
    return [(image + torch.randn(image.shape, generator=generator) * levels / 255).clamp(0, 1) for image in images]


def with_grid(images: list[torch.Tensor], levels: float) -> list[torch.Tensor]:
    """Each image plus a pattern that repeats every 4 pixels in both directions (``levels`` RMS, zero mean)."""
    pattern = torch.randn(4, 4, generator=torch.Generator().manual_seed(3))
    pattern = (pattern - pattern.mean()) / pattern.std(correction=0) * levels / 255
    return [(image + pattern.repeat(16, 16)[: image.shape[-2], : image.shape[-1]]).clamp(0, 1) for image in images]


def _blocks(reals: list[torch.Tensor], sims: list[torch.Tensor], cleans: list[torch.Tensor]) -> tuple:
    """``(edge excess, mid excess, the blocks finding)`` of ``sims`` against ``reals``."""
    masks = [flat_mask(clean) for clean in cleans]
    real, sim = StatisticSet.measure(reals, cleans, masks), StatisticSet.measure(sims, cleans, masks)
    where = findings(real, sim, family_gaps(real, sim), {}, compare_grid(sims, reals))
    edge, mid = block_excess(real.values()["blocks"], sim.values()["blocks"])
    return edge, mid, next(entry["finding"] for entry in where if entry["axis"] == "blocks")


def test_a_4_pixel_pattern_is_seen_as_the_networks_grid_not_a_codec() -> None:
    cleans = photo_crops(6, seed=0)
    reals = noisy(cleans, seed=1)
    sims = with_grid(noisy(cleans, seed=2), levels=3.0)
    grid = compare_grid(sims, reals)
    assert grid.significant and grid.ratio is not None and grid.ratio > 3, grid
    assert grid.describe().startswith(f"the simulation carries a 4-pixel grid {grid.ratio:.1f}× the camera's")
    edge, mid, finding = _blocks(reals, sims, cleans)
    assert abs(edge) > 0.01 and mid == pytest.approx(edge, rel=0.3)  # 3 ≡ 7 (mod 4): a 4-pixel grid moves both alike
    assert "suspects: the network's 4-pixel grid" in finding and "not a codec" in finding, finding


def test_a_codecs_blocks_are_left_to_the_codec() -> None:
    cleans = photo_crops(6, seed=0)
    reals = noisy(cleans, seed=1)
    codec = JPEG(quality=15)
    with torch.no_grad():
        sims = [codec(image[None])[0] for image in noisy(cleans, seed=2)]
    edge, mid, finding = _blocks(reals, sims, cleans)
    assert edge > 2 * max(mid, 0.0), (edge, mid)  # a codec raises the block edges alone
    assert "network" not in finding and "jpeg" in finding, finding


def test_no_grid_and_no_texture_gap_between_two_draws_of_the_same_camera() -> None:
    cleans = photo_crops(6, seed=0)
    reals, sims = noisy(cleans, seed=1, levels=2.0), noisy(cleans, seed=2, levels=2.0)
    assert not compare_grid(sims, reals).significant
    texture = compare_texture(sims, reals)
    assert not texture.significant and texture.direction is None
    assert texture.describe().startswith("texture within the camera's in every band")


def test_texture_too_smooth_and_too_sharp_are_named_by_band() -> None:
    cleans = photo_crops(6, seed=0)
    reals = noisy(cleans, seed=1)
    smooth = compare_texture([blur_image(image[None], 1.5)[0] for image in reals], reals)
    assert smooth.direction == "smooth"
    assert smooth.bands_significant[-2] and smooth.log2[-2] < -1, smooth  # 0.25–0.35 cycles/px
    first, last, value = smooth.runs()[0]
    assert first <= 3 <= last and value < -1
    edges = f"{BAND_EDGES[first]:g}–{BAND_EDGES[last + 1]:g} cycles/px"
    assert smooth.describe().startswith(f"texture too smooth at {edges} by {abs(value):.2f} log2"), smooth.describe()
    sharpener = Sharpen(sigma=1.0, amount=1.5)
    with torch.no_grad():
        sharp = compare_texture([sharpener(image[None])[0] for image in reals], reals)
    assert sharp.direction == "sharp" and "too sharp" in sharp.describe(), sharp
    assert not sharp.bands_significant[0]  # the lowest band is left as it was


def test_bad_inputs_name_the_argument() -> None:
    image = torch.zeros(3, 16, 16)
    with pytest.raises(ValueError, match="sims and reals must be non-empty and as long, got 1 and 2"):
        compare_grid([image], [image, image])
    with pytest.raises(ValueError, match="sims and reals must be non-empty and as long, got 0 and 0"):
        compare_texture([], [])


def _camera_pairs(camera: CameraProfile | VirtualCamera, count: int, seed: int) -> list[tuple]:
    generator = torch.Generator().manual_seed(seed + 100)
    out = []
    with torch.no_grad():
        for clean in photo_crops(count, seed):
            out.append((clean, camera(clean[None], camera.make_params((1, *clean.shape), generator))[0]))
    return out


def test_a_network_that_prints_a_checkerboard_is_named_by_its_grid() -> None:
    """The camera is the network of the paper-network built-in (as shipped until 2026-11-27); the profile's network
    has its last layer's weights moved by ±0.004 in a 2×2 checkerboard (as in bench/bench_diagnose.py): the
    diagnosis names the grid and its size."""
    clean = load_profile(PAPER_BUILT_IN).network
    checker = copy.deepcopy(clean)
    with torch.no_grad():
        checker.decode2.weight.add_(0.004 * torch.tensor([[1.0, -1.0], [-1.0, 1.0]]))
    camera = CameraProfile(clean, [Noise(a=0.0002)])
    profile = CameraProfile(checker, [Noise(a=0.0002)], name="checker")
    report = diagnose(
        profile,
        _camera_pairs(camera, 6, seed=0),
        held_out=_camera_pairs(camera, 6, seed=1),
        candidates=["jpeg"],
        kinds=("add",),
        critic=False,
    )
    grid = next(entry for entry in report.visible if entry["look"] == "grid")
    assert grid["significant"] and grid["before"]["ratio"] > 3, grid
    assert "the simulation carries a 4-pixel grid" in grid["finding"]
    assert "What a person sees: the simulation carries a 4-pixel grid" in report.verdict, report.verdict
    assert "add jpeg" not in report.accepted
    data = json.loads(report.to_json())
    assert [entry["look"] for entry in data["visible"]] == ["grid", "texture"]
    assert "What a person sees" in report.to_html()


@pytest.fixture(scope="module")
def too_soft() -> DiagnosisReport:
    """A profile whose blur is 2.3× the camera's."""
    camera = VirtualCamera([Blur(sigma_x=0.7), Noise(a=0.0002)], scale=1.0)
    profile = CameraProfile(None, [Blur(sigma_x=1.6), Noise(a=0.0002)], name="too-soft")
    return diagnose(
        profile,
        _camera_pairs(camera, 6, seed=0),
        held_out=_camera_pairs(camera, 6, seed=1),
        candidates=["sharpen", "blur"],
        critic=False,
    )


@pytest.mark.slow
def test_a_profile_that_blurs_too_much_is_too_smooth_and_a_blur_or_sharpen_change_mends_it(
    too_soft: DiagnosisReport,
) -> None:
    texture = next(entry for entry in too_soft.visible if entry["look"] == "texture")
    assert texture["significant"] and texture["finding"].startswith("texture too smooth at "), texture
    assert "What a person sees: texture too smooth" in too_soft.verdict
    assert too_soft.accepted[:1] in (["refit blur"], ["remove blur"], ["add sharpen"]), too_soft.accepted
    assert not any(texture["after"]["significant"]), texture["after_finding"]
    assert "With the changes:" not in too_soft.verdict  # nothing is still seen
    tried = {f"{change['kind']} {change['name']}" for change in too_soft.changes}
    assert "add sharpen" in tried  # sharpening is a candidate the search tries


def test_a_camera_that_sharpens_is_mended_by_adding_sharpen() -> None:
    camera = VirtualCamera([Noise(a=0.0002), Sharpen(sigma=1.2, amount=1.2)], scale=1.0)
    profile = CameraProfile(None, [Noise(a=0.0002)], name="unsharpened")
    report = diagnose(
        profile,
        _camera_pairs(camera, 6, seed=0),
        held_out=_camera_pairs(camera, 6, seed=1),
        candidates=["sharpen", "blur"],
        critic=False,
    )
    texture = next(entry for entry in report.visible if entry["look"] == "texture")
    assert texture["significant"] and "too smooth" in texture["finding"], texture
    assert report.accepted[:1] == ["add sharpen"], report.accepted
    assert report.fitted_params["sharpen"]["amount"] == pytest.approx(1.2, rel=0.3)


def test_the_verdict_says_what_a_change_leaves_seen() -> None:
    """A change the statistics accept can deepen what a person sees (on City100 the accepted blur refit leaves the
    texture smoother still): the verdict then says what is still seen with the changes."""
    from camdegrade.diagnose.verdict import seen_clause

    cleans = photo_crops(6, seed=0)
    reals = noisy(cleans, seed=1)
    soft = [blur_image(image[None], 1.0)[0] for image in reals]
    softer = [blur_image(image[None], 2.0)[0] for image in reals]
    deepened = seen_clause(visible(reals, soft, softer))
    assert deepened.startswith(" What a person sees: texture too smooth at "), deepened
    assert " With the changes: texture too smooth at " in deepened
    mended = seen_clause(visible(reals, soft, reals))
    assert "What a person sees: texture too smooth" in mended and "With the changes" not in mended
    assert seen_clause(visible(reals, reals, reals)) == ""
