"""The diagnosis' critic: what it sees in the report (its surest patches, its accuracy by group)."""

from __future__ import annotations

import base64
import io
import json
import re

import pytest
import torch
from PIL import Image

from camdegrade.diagnose import DiagnosisReport, diagnose
from camdegrade.diagnose.report._html import png_url
from camdegrade.diagnose.report.critic_html import DETAIL_GAIN
from camdegrade.effects import Noise, Tone
from camdegrade.measures.critic import PATCH, alternate_scenes
from camdegrade.measures.critic.explain import GROUPINGS, crossfit_critic_test, surest_png
from camdegrade.pairs.pairset import PairSet
from camdegrade.profile import CameraProfile
from camdegrade.sim import VirtualCamera
from effects_images import patch_chart, photo

torch.set_num_threads(1)


def scenes(count: int, size: int, seed: int) -> list[torch.Tensor]:
    """Photo crops and patch charts, different per seed."""
    generator = torch.Generator().manual_seed(seed)
    names = ("astronaut", "coffee", "chelsea")
    out = []
    for index in range(count):
        if index % 3 == 2:
            out.append(patch_chart(size, patches=max(1, size // 48), seed=seed * 100 + index))
            continue
        full = photo(names[index % 3], 3 * size)
        top, left = (int(torch.randint(0, side - size + 1, (1,), generator=generator)) for side in full.shape[-2:])
        out.append(full[:, top : top + size, left : left + size].clamp(0, 1))
    return out


def camera_pairs(camera: VirtualCamera, count: int, size: int, seed: int) -> list[tuple[torch.Tensor, torch.Tensor]]:
    generator = torch.Generator().manual_seed(seed + 1)
    with torch.no_grad():
        return [(clean, camera(clean[None], generator=generator)[0]) for clean in scenes(count, size, seed)]


def named(prefix: str, pairs: list[tuple[torch.Tensor, torch.Tensor]]) -> PairSet:
    """``pairs`` as a pair set, each pair its own scene, named ``prefix0``, ``prefix1``, ..."""
    names = [f"{prefix}{index}" for index in range(len(pairs))]
    return PairSet(pairs, list(names), names)


def diagnose_adding(profile: CameraProfile, camera: VirtualCamera, effect: str, held_out: int = 6) -> DiagnosisReport:
    """:func:`diagnose` of ``profile`` on 6 pairs of ``camera`` and ``held_out`` held-out ones (64², seeds 0 and 1),
    the only change it may make adding ``effect``."""
    return diagnose(
        profile,
        named("cal-", camera_pairs(camera, 6, 64, seed=0)),
        held_out=named("held-", camera_pairs(camera, held_out, 64, seed=1)),
        candidates=[effect],
        kinds=("add",),
    )


@pytest.fixture(scope="module")
def toned() -> DiagnosisReport:
    """A camera with a tone curve, a profile without: the critic tells most patches apart before, fewer after."""
    camera = VirtualCamera([Noise(a=0.0005), Tone(gamma=1.3, black=0.03)], scale=1.0)
    profile = CameraProfile(None, [Noise(a=0.0005)], name="no-tone")
    return diagnose_adding(profile, camera, "tone")


@pytest.mark.slow  # the fixture: a diagnosis with four critics, about 30 s on one core
def test_the_critic_never_sees_a_pair_the_change_was_fitted_on(toned: DiagnosisReport) -> None:
    """The accepted change is fitted on the calibration pairs; each critic is trained on one part of the held-out
    pairs and scored on the other, both ways, so every held-out pair is scored by a critic that never saw it."""
    assert toned.accepted == ["add tone"]
    held = {f"held-{index}" for index in range(6)}
    for label in ("before", "after"):
        folds = toned.critic[label]["folds"]
        assert len(folds) == 2
        for fold in folds:
            trained, scored = set(fold["trained_on"]), set(fold["scored_on"])
            assert trained and scored and not trained & scored, fold
            assert trained | scored == held, fold  # no calibration pair on either side
            assert 0.0 <= fold["accuracy"] <= 1.0
        assert folds[0]["trained_on"] == folds[1]["scored_on"] and folds[1]["trained_on"] == folds[0]["scored_on"]
        assert sorted(toned.critic[label]["scored_on"]) == sorted(held)
        assert toned.critic[label]["pairs"] == 6
        mean = sum(fold["accuracy"] * len(fold["scored_on"]) for fold in folds) / 6  # 24 patches a pair, both folds
        assert toned.critic[label]["accuracy"] == pytest.approx(mean, abs=1e-3)


@pytest.mark.slow
def test_the_json_carries_the_accuracy_by_group_and_the_surest_patches(toned: DiagnosisReport, tmp_path) -> None:
    data = json.loads(toned.write_json(tmp_path / "r.json").read_text())
    assert data["accepted"] == ["add tone"]
    for label in ("before", "after"):
        critic = data["critic"][label]
        assert list(critic["by_group"]) == list(GROUPINGS)
        for grouping, tiers in critic["by_group"].items():
            assert sum(tier["patches"] for tier in tiers.values()) == critic["patches"], grouping
            right = sum(tier["accuracy"] * tier["patches"] for tier in tiers.values() if tier["patches"])
            assert right / critic["patches"] == pytest.approx(critic["accuracy"], abs=1e-3)
        assert {entry["label"] for entry in critic["surest"]} == {"real", "simulated"}
        assert set(critic["group_edges"]) == set(GROUPINGS)
    assert data["critic"]["before"]["accuracy"] > 0.9
    assert data["critic"]["after"]["accuracy"] < data["critic"]["before"]["accuracy"]


@pytest.mark.slow
def test_a_second_critic_sees_the_image_alone(toned: DiagnosisReport) -> None:
    """Beside the critic with the clean source, one that sees the image alone (what a model trained on the
    simulation sees), on the same folds. It sees less: a tone curve (γ 1.3) on varied photos is plain beside the
    clean source (above 0.9) and not from the image alone (0.52 here)."""
    before, after = toned.critic["before (image only)"], toned.critic["after (image only)"]
    assert before["folds"] == [
        {**fold, "accuracy": entry["accuracy"]} for fold, entry in zip(toned.critic["before"]["folds"], before["folds"])
    ]
    assert before["accuracy"] < toned.critic["before"]["accuracy"] - 0.2, (before, toned.critic["before"])
    assert before["patches"] == toned.critic["before"]["patches"] and after["pairs"] == 6
    assert f"From the image alone: {before['accuracy']:.2f}" in toned.verdict
    assert toned.critic_surest["after (image only)"]


@pytest.mark.slow
def test_the_html_shows_the_surest_patches_real_beside_simulated_and_the_table(toned: DiagnosisReport) -> None:
    page = toned.to_html()
    for label in ("before", "after"):
        patches = toned.critic_surest[label]
        assert patches and {p.label for p in patches} == {"real", "simulated"}
        names = toned.critic[label]["scored_on"]
        url = png_url(surest_png(patches, scale=2, names=names, detail_gain=DETAIL_GAIN))
        assert url in page, label
        picture = Image.open(io.BytesIO(base64.b64decode(url.split(",", 1)[1])))
        assert picture.height >= len([p for p in patches if p.label == "real"]) * 2 * PATCH  # 2x
        assert f"Profile {label}: the held-out patches the critic is surest about" in page
    assert "Where it decides" in page
    table = page[page.index("Where it decides") :]
    for grouping, (_, names) in GROUPINGS.items():
        assert f"<td>{grouping}</td>" in table
        assert re.search(rf"<td>{names[0]} (\d\.\d\d|n/a) \(\d+\)</td>", table), grouping


@pytest.mark.slow
def test_the_reported_interval_contains_a_fresh_critics_accuracy() -> None:
    """A camera whose noise is 2× the profile's (in std) and a tone curve the profile lacks: adding the tone leaves
    the noise for the critic to see. The accuracy the diagnosis reports after the change, and its interval, must
    hold a fresh critic's accuracy: the same two-fold critic on 12 new pairs of the camera, simulated by the
    changed profile."""
    camera = VirtualCamera([Noise(a=0.0008), Tone(gamma=1.3, black=0.03)], scale=1.0)
    profile = CameraProfile(None, [Noise(a=0.0002)], name="quiet")
    report = diagnose_adding(profile, camera, "tone", held_out=12)
    assert report.accepted == ["add tone"]
    after = report.critic["after"]
    assert 0.6 < after["accuracy"] < 0.95 and after["high"] - after["low"] > 0.05, after  # neither chance nor sure
    fresh = camera_pairs(camera, 12, 64, seed=20)
    cleans, reals = [clean for clean, _ in fresh], [real for _, real in fresh]
    sims = report.profile.simulate(cleans, 5, stream="fresh")
    trains = alternate_scenes([str(index) for index in range(12)])
    result, _, _ = crossfit_critic_test((cleans, reals, sims), trains, seed=0)
    assert after["low"] <= result.accuracy <= after["high"], (after, result)


def test_a_crossfit_critic_needs_pairs_on_both_sides() -> None:
    images = [torch.zeros(3, 32, 32)] * 2
    with pytest.raises(ValueError, match="trains must mark some but not all of the 2 pairs, got 2 of 2"):
        crossfit_critic_test((images, images, images), [True, True], seed=0)
