"""Explaining a trained critic: its surest patches, its accuracy by group, and their picture."""

from __future__ import annotations

import io
from dataclasses import replace

import numpy as np
import pytest
import torch
from PIL import Image

from camdegrade.functional.analysis.images import box_mean
from camdegrade.functional.optics.blur import blur_image
from camdegrade.measures.critic import PATCH, CriticNet, Patches, critic_test, train_critic
from camdegrade.measures.critic.explain import (
    GROUPINGS,
    accuracy_by_group,
    explain_critic,
    explained_critic_test,
    render_surest,
    surest_patches,
    surest_png,
)

STEPS = 80


def _sets(seed: int, pairs: int = 4) -> tuple[list, list, list]:
    """Smooth clean images with a left-to-right ramp of brightness; real = clean + noise of 8 levels, sim = clean."""
    generator = torch.Generator().manual_seed(seed)
    ramp = torch.linspace(0.1, 0.8, 64)[None, None, :]
    cleans = [
        (ramp + 0.2 * blur_image(torch.rand(1, 3, 64, 64, generator=generator), 3.0)[0]).clamp(0, 1)
        for _ in range(pairs)
    ]
    reals = [(c + torch.randn(c.shape, generator=generator) * (8 / 255)).clamp(0, 1) for c in cleans]
    return cleans, reals, cleans


@pytest.fixture(scope="module")
def trained() -> tuple[CriticNet, Patches]:
    calibration, held_out = _sets(1), _sets(2)
    net = train_critic(Patches.sample(*calibration, 0, "critic-calibration", image_only=True), 0, STEPS)
    return net, Patches.sample(*held_out, 0, "critic-held-out", image_only=True)


def _fine_std(image: torch.Tensor) -> float:
    return float((image - box_mean(image, 3)).std())


def test_the_surest_patches_are_of_their_class_and_show_the_noisy_one_as_real(trained) -> None:
    net, held = trained
    surest = surest_patches(net, held, k=3)
    assert [p.label for p in surest] == ["real"] * 3 + ["simulated"] * 3
    assert all(p.probability > 0.9 for p in surest), [p.probability for p in surest]
    for label in ("real", "simulated"):
        probabilities = [p.probability for p in surest if p.label == label]
        assert probabilities == sorted(probabilities, reverse=True)
    for patch in surest:
        assert patch.real.shape == patch.simulated.shape == (3, PATCH, PATCH)
        # the partner is the other image at the same position: same content, and only the real one is noisy
        assert _fine_std(patch.real) > 3 * _fine_std(patch.simulated)
        assert (patch.real - patch.simulated).abs().mean() < 0.03
        assert 0 <= patch.pair < 4 and 0 <= patch.top <= 64 - PATCH and 0 <= patch.left <= 64 - PATCH
        # the detail planes are what the critic saw: the image less its 3x3 mean (inside the patch's border)
        inside = (..., slice(1, -1), slice(1, -1))
        torch.testing.assert_close(patch.real_detail[inside], (patch.real - box_mean(patch.real, 3))[inside])


def test_k_larger_than_a_class_returns_the_whole_class(trained) -> None:
    net, held = trained
    surest = surest_patches(net, held, k=10_000)
    assert len(surest) == len(held)


def test_per_pair_takes_the_surest_of_each_pair_first(trained) -> None:
    net, held = trained
    limited = surest_patches(net, held, k=3, per_pair=1)
    for label in ("real", "simulated"):
        pairs = [p.pair for p in limited if p.label == label]
        assert len(pairs) == len(set(pairs)) == 3
    unlimited = surest_patches(net, held, k=1)
    assert [p.probability for p in unlimited] == [limited[0].probability, limited[3].probability]


def test_group_counts_sum_to_the_patch_count_and_split_in_terciles(trained) -> None:
    net, held = trained
    groups, edges = accuracy_by_group(net, held)
    assert list(groups) == list(GROUPINGS)
    for grouping, tiers in groups.items():
        counts = [tier["patches"] for tier in tiers.values()]
        assert sum(counts) == len(held), (grouping, counts)
        assert all(count % 2 == 0 for count in counts)  # real and simulated of a position stay together
        assert edges[grouping][0] <= edges[grouping][1]
    for grouping in ("texture", "intensity", "colour"):  # continuous values: terciles of about a third each
        counts = [tier["patches"] for tier in groups[grouping].values()]
        assert max(counts) - min(counts) <= len(held) // 6, (grouping, counts)
    low, high = torch.quantile(held.intensity, torch.tensor([1 / 3, 2 / 3])).tolist()
    assert edges["intensity"] == pytest.approx((low, high))
    assert groups["intensity"]["dark"]["patches"] == int((held.intensity <= low).sum())
    assert groups["intensity"]["bright"]["patches"] == int((held.intensity > high).sum())
    overall = sum(t["accuracy"] * t["patches"] for t in groups["texture"].values()) / len(held)
    assert overall > 0.9


def test_explained_test_scores_exactly_as_the_critic_test() -> None:
    calibration, held_out = _sets(3, pairs=2), _sets(4, pairs=2)
    result, explanation = explained_critic_test(calibration, held_out, seed=5, steps=20, image_only=True, k=2)
    expected = critic_test(calibration, held_out, seed=5, steps=20, image_only=True)
    assert replace(result, seconds=0.0) == replace(expected, seconds=0.0)
    assert len(explanation.surest) == 4
    assert "| texture |" in explanation.table()
    assert explanation.to_dict()["surest"][0]["label"] == "real"


def test_paired_critic_patches_show_the_images_not_the_residual() -> None:
    calibration, held_out = _sets(5, pairs=2), _sets(6, pairs=2)
    _, explanation = explained_critic_test(calibration, held_out, seed=0, steps=10, image_only=False, k=1)
    cleans, reals, _ = held_out
    patch = explanation.surest[0]
    window = (..., slice(patch.top, patch.top + PATCH), slice(patch.left, patch.left + PATCH))
    torch.testing.assert_close(patch.real, reals[patch.pair][window])
    torch.testing.assert_close(patch.simulated, cleans[patch.pair][window])


def test_the_same_seed_gives_the_same_png_bytes() -> None:
    def png() -> bytes:
        calibration, held_out = _sets(7, pairs=2), _sets(8, pairs=2)
        _, explanation = explained_critic_test(calibration, held_out, seed=3, steps=15, image_only=True, k=2)
        return surest_png(explanation.surest, names=["a", "b"], title="test")

    first = png()
    assert first == png()
    picture = Image.open(io.BytesIO(first))
    assert picture.mode == "RGB" and picture.height >= 2 * 2 * PATCH


def test_the_picture_shows_the_patches_at_twice_their_size_nearest_neighbour(trained) -> None:
    net, held = trained
    surest = surest_patches(net, held, k=1)
    picture = render_surest(surest, scale=2)
    pixels = torch.from_numpy(np.array(picture)).permute(2, 0, 1)
    zoomed = (surest[0].real * 255).round().to(torch.uint8).repeat_interleave(2, 1).repeat_interleave(2, 2)
    corner = zoomed[:, :8, :8]
    hits = (pixels.unfold(1, 8, 1).unfold(2, 8, 1) == corner[:, None, None]).all(0).all(-1).all(-1).nonzero()
    side = 2 * PATCH
    assert any(torch.equal(pixels[:, y : y + side, x : x + side], zoomed) for y, x in hits.tolist())


def test_the_detail_view_adds_two_tiles_per_patch(trained) -> None:
    net, held = trained
    surest = surest_patches(net, held, k=2)
    plain, detailed = render_surest(surest), render_surest(surest, detail_gain=4.0)
    assert detailed.height == plain.height and detailed.width > plain.width
    first = surest[0]
    assert replace(first, margin=1.0).caption(["x"] * 4) == f"x y{first.top} x{first.left} p 0.731"
    assert replace(first, margin=20.0).caption().endswith("logit 20.0")
    assert replace(first, margin=-1000.0).probability == 0.0


def test_bad_arguments_raise_typed_errors(trained) -> None:
    net, held = trained
    with pytest.raises(ValueError, match="k must be a positive integer, got k=0"):
        surest_patches(net, held, k=0)
    with pytest.raises(TypeError, match="k must be a positive integer, got str"):
        surest_patches(net, held, k="3")
    with pytest.raises(TypeError, match="net must be a CriticNet"):
        explain_critic("net", held)
    with pytest.raises(TypeError, match="patches must be a critic Patches"):
        accuracy_by_group(net, held.inputs)
    with pytest.raises(ValueError, match="the 6 planes the critic was trained on, got 11"):
        paired = Patches.sample(*_sets(9, pairs=1), 0, "x", image_only=False)
        explain_critic(net, paired)
    with pytest.raises(ValueError, match="per_pair must be a positive integer, got per_pair=0"):
        surest_patches(net, held, k=2, per_pair=0)
    with pytest.raises(ValueError, match="at least one SurePatch"):
        render_surest([])
    with pytest.raises(ValueError, match="detail_gain must be a positive number or None, got detail_gain=0"):
        render_surest(surest_patches(net, held, k=1), detail_gain=0)
    with pytest.raises(ValueError, match="scale must be a positive integer"):
        render_surest(surest_patches(net, held, k=1), scale=0)
