"""The sim-to-real diagnosis: gap fairness, attribution on a withheld effect, control, JSON schema, HTML, CLI."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
import torch
import torch.nn.functional as F

from camdegrade.__main__ import main
from camdegrade.diagnose import DiagnosisReport, diagnose
from camdegrade.diagnose.attribution.changes import add_effect
from camdegrade.diagnose.heldout import HeldOut
from camdegrade.diagnose.report import REQUIRED_KEYS
from camdegrade.effects import EFFECTS, JPEG, Noise, Tone, Vignetting
from camdegrade.fitting.in_chain import fit_noise_stage
from camdegrade.functional.analysis.images import box_mean, flat_mask
from camdegrade.functional.analysis.noise import measure_set
from camdegrade.io import write_image
from camdegrade.measures import FAMILIES, StatisticSet, bootstrap_indices, family_gaps, gap, measurement_scale
from camdegrade.pairs.pairset import PairSet
from camdegrade.profile import CameraProfile, load_profile
from camdegrade.sim import VirtualCamera
from conftest import PAPER_BUILT_IN
from effects_images import patch_chart, photo

torch.set_num_threads(1)


def _content(count: int, size: int, seed: int) -> list[torch.Tensor]:
    """Photo crops and patch charts (flat areas at many intensities), different per seed."""
    generator = torch.Generator().manual_seed(seed)
    names = ("astronaut", "coffee", "chelsea")
    images = []
    for index in range(count):
        if index % 3 == 2:  # patches wide enough to stay flat after the flat mask's 8-pixel erosion
            images.append(patch_chart(size, patches=max(1, size // 48), seed=seed * 100 + index))
            continue
        full = photo(names[index % 3], 3 * size)
        top = int(torch.randint(0, full.shape[-2] - size + 1, (1,), generator=generator))
        left = int(torch.randint(0, full.shape[-1] - size + 1, (1,), generator=generator))
        images.append(full[:, top : top + size, left : left + size].clamp(0, 1))
    return images


def _pairs(camera: VirtualCamera, count: int, size: int, seed: int) -> list[tuple[torch.Tensor, torch.Tensor]]:
    generator = torch.Generator().manual_seed(seed + 1)
    with torch.no_grad():
        return [(clean, camera(clean[None], generator=generator)[0]) for clean in _content(count, size, seed)]


def _camera(*effects) -> VirtualCamera:
    return VirtualCamera(list(effects), scale=1.0)


def test_gap_is_fair_to_noise() -> None:
    """A correct noise stage lowers the gap; paired MSE would punish it."""
    camera = _camera(Noise(a=0.004, b=1e-5), Tone(gamma=1.1))
    held = HeldOut.build(_pairs(camera, 12, 64, seed=3), seed=0, stream="held-out")
    without, _ = held.statistics(CameraProfile(None, [Tone(gamma=1.1)]))
    correct, sims = held.statistics(CameraProfile(None, [Noise(a=0.004, b=1e-5), Tone(gamma=1.1)]))
    assert gap(held.real, correct) < 0.5 * gap(held.real, without)
    mse_without = sum(
        float((s - r).pow(2).mean())
        for s, r in zip(
            CameraProfile(None, [Tone(gamma=1.1)]).simulate(held.cleans, 0, stream="held-out"), held.reals, strict=True
        )
    )
    mse_correct = sum(float((s - r).pow(2).mean()) for s, r in zip(sims, held.reals, strict=True))
    assert mse_correct > mse_without  # why paired MSE cannot be the measure


def test_box_filter_matches_the_two_dimensional_mean() -> None:
    image = torch.rand(3, 40, 33, generator=torch.Generator().manual_seed(0))
    for size in (5, 9, 17):
        reference = F.avg_pool2d(image[:, None], size, stride=1, padding=size // 2, count_include_pad=False)[:, 0]
        assert torch.allclose(box_mean(image, size), reference, atol=1e-6)


def test_noise_family_compares_levels_relatively() -> None:
    """A 10 % noise-level miss counts the same at std 2 and at std 20 levels (noise levels are scales)."""
    cleans = [torch.full((3, 64, 64), 0.5)]
    masks = [torch.ones(64, 64, dtype=torch.bool)]
    generator = torch.Generator().manual_seed(0)
    scores = []
    for level in (2.0, 20.0):
        normal = [torch.randn(3, 64, 64, generator=generator) for _ in range(2)]
        real = StatisticSet.measure([cleans[0] + normal[0] * level / 255], cleans, masks)
        sim = StatisticSet.measure([cleans[0] + normal[1] * 1.1 * level / 255], cleans, masks)
        scores.append(family_gaps(real, sim)["noise"])
    assert scores[0] == pytest.approx(scores[1], rel=0.15)
    assert scores[0] > 1.0


def test_components_resting_on_one_pair_are_left_out_of_the_gap() -> None:
    """An intensity bin only one of eight pairs populates has no bootstrap spread: it must not enter the gap."""
    cleans = [torch.full((3, 64, 64), 0.3) for _ in range(7)] + [torch.full((3, 64, 64), 0.9)]
    masks = [torch.ones(64, 64, dtype=torch.bool)] * 8
    generator = torch.Generator().manual_seed(1)
    reals = [clean + torch.randn(3, 64, 64, generator=generator) * 0.01 for clean in cleans]
    real = StatisticSet.measure(reals, cleans, masks)
    sim = StatisticSet.measure(cleans, cleans, masks)
    scale = measurement_scale(real, sim, bootstrap_indices(8, 100, seed=0))
    noise_scale = scale["noise"].reshape(3, -1)
    assert torch.isfinite(noise_scale[:, 2]).all()  # clean 0.3: seven pairs
    assert torch.isnan(noise_scale[:, 7]).all()  # clean 0.9: one pair


def test_noise_level_is_calibrated_through_the_later_stages() -> None:
    """Noise at the sensor, then a strong tone curve and JPEG: fitted against the end of the chain, the stage is
    off where the later stages reshape the noise; calibrated by simulating the chain, its noise per intensity bin
    matches the camera's (on flat pixels)."""
    later = [Tone(gamma=0.6, black=0.04, white=0.9), JPEG(quality=50)]
    camera = _camera(Noise(a=0.003, b=2e-5), *later)
    profile = CameraProfile(None, list(later))
    pairs = _pairs(camera, 18, 128, seed=11)
    cleans, reals = [c for c, _ in pairs], [r for _, r in pairs]
    masks = [flat_mask(clean) for clean in cleans]
    real = measure_set(reals, cleans, masks)

    def ratios(noise: Noise) -> torch.Tensor:  # simulated / real noise std per measurable bin
        simulated = measure_set(add_effect(profile, noise).simulate(cleans, 9), cleans, masks)
        ratio = simulated.std() / real.std()
        return ratio[torch.isfinite(ratio)]

    closed_form = Noise.fit(profile.simulate(cleans, 0, deterministic=True), reals, rounds=0, banding=False)
    calibrated = fit_noise_stage(profile, cleans, reals)
    errors = (ratios(calibrated) - 1).abs()
    assert errors.numel() >= 12
    assert ratios(calibrated).median() == pytest.approx(1.0, abs=0.05)
    assert (errors <= 0.15).double().mean() >= 0.8  # bins of a few thousand correlated pixels scatter
    assert errors.median() < 0.5 * (ratios(closed_form) - 1).abs().median()


def test_split_keeps_scenes_apart() -> None:
    scenes = ["a", "a", "b", "b", "c", "d", "e", "e"]
    image = torch.zeros(3, 4, 4)
    pair_set = PairSet([(image, image)] * len(scenes), scenes, [str(i) for i in range(len(scenes))])
    calibration, held_out = pair_set.split(0.5, seed=0)
    assert sorted(calibration.names + held_out.names, key=int) == pair_set.names
    assert not set(calibration.scenes) & set(held_out.scenes)
    assert len(calibration) and len(held_out)


@pytest.fixture(scope="module")
def vignetting_report() -> DiagnosisReport:
    camera = _camera(Vignetting(k1=-0.35), Noise(a=0.002), JPEG(quality=80))
    profile = CameraProfile(None, [Noise(a=0.002), JPEG(quality=80)], name="no-vignetting")
    calibration = _pairs(camera, 16, 64, seed=0)
    held_out = _pairs(camera, 16, 64, seed=1)
    return diagnose(profile, calibration, held_out=held_out, candidates=["vignetting", "tone", "blur", "noise"])


@pytest.mark.slow
def test_withheld_vignetting_is_named_and_closes_the_gap(vignetting_report: DiagnosisReport) -> None:
    report = vignetting_report
    assert report.added[0] == "vignetting" and report.accepted[0] == "add vignetting"
    assert report.effects[0]["name"] == "vignetting"
    assert report.changes[0]["kind"] == "add" and report.changes[0]["name"] == "vignetting"
    assert report.fraction_closed >= 0.7
    assert report.gap_after < report.gap_before
    k1 = report.fitted_params["vignetting"]["k1"]
    assert k1 == pytest.approx(-0.35, rel=0.25)
    assert report.where[0]["axis"] in ("spatial", "intensity", "color")
    assert report.profile is not None and "vignetting" in report.profile.effect_names


@pytest.mark.slow  # the vignetting diagnosis (a module fixture, about 30 s of CPU) is most of it
def test_json_schema(vignetting_report: DiagnosisReport, tmp_path: Path) -> None:
    data = json.loads(vignetting_report.write_json(tmp_path / "r.json").read_text())
    assert list(data)[: len(REQUIRED_KEYS)] == list(REQUIRED_KEYS)
    for key in ("gap_before", "gap_after", "noise_floor"):
        assert isinstance(data[key], float)
    assert all(set(entry) >= {"axis", "finding", "score"} for entry in data["where"])
    assert {entry["axis"] for entry in data["where"]} == set(FAMILIES)
    assert all(isinstance(entry["axis"], str) and isinstance(entry["finding"], str) for entry in data["where"])
    assert all(isinstance(entry["score"], float) for entry in data["where"])
    for entry in data["effects"]:
        assert set(entry) >= {"name", "gap_after", "reduction", "params"}
        assert entry["name"] in EFFECTS and isinstance(entry["params"], dict)
        assert isinstance(entry["gap_after"], float) and isinstance(entry["reduction"], float)
    reductions = [entry["reduction"] for entry in data["effects"] if "error" not in entry]
    assert reductions == sorted(reductions, reverse=True)
    assert all(isinstance(name, str) and name in EFFECTS for name in data["added"])
    kinds = {entry["kind"] for entry in data["changes"]}
    assert "add" in kinds and kinds <= {"add", "remove", "refit", "network"}
    for entry in data["changes"]:
        assert set(entry) >= {"kind", "name", "gap_after", "reduction", "params"}
        assert isinstance(entry["gap_after"], float) and isinstance(entry["params"], dict)
    assert data["accepted"] and data["accepted"][0] == "add vignetting"
    for label in ("before", "after"):
        critic = data["critic"][label]
        assert 0.0 <= critic["low"] <= critic["accuracy"] <= critic["high"] <= 1.0
        assert critic["patches"] > 0 and set(critic["by_texture"]) == {"flat", "textured"}
    assert data["critic"]["before"]["accuracy"] > data["critic"]["after"]["accuracy"]
    assert data["skipped"] == []


@pytest.mark.slow  # the vignetting diagnosis (a module fixture, about 30 s of CPU) is most of it
def test_html_is_one_self_contained_file(vignetting_report: DiagnosisReport, tmp_path: Path) -> None:
    page = vignetting_report.write_html(tmp_path / "r.html").read_text()
    assert page.startswith("<!DOCTYPE html>")
    assert vignetting_report.verdict.split(":")[0] in page
    assert page.index("class='verdict'") < page.index("<h2>")  # verdict first
    assert not re.search(r"(src|href)\s*=\s*['\"](?!data:)", page)
    assert "<link" not in page and "<script" not in page and "@import" not in page and "url(" not in page
    assert "data:image/png;base64," in page
    assert "Learned critic" in page and "A flat region at 1:1" in page


@pytest.mark.slow
def test_control_names_nothing() -> None:
    camera = _camera(Vignetting(k1=-0.2), Noise(a=0.002))
    profile = CameraProfile(None, [Vignetting(k1=-0.2), Noise(a=0.002)])
    report = diagnose(
        profile,
        _pairs(camera, 12, 64, seed=5),
        held_out=_pairs(camera, 12, 64, seed=6),
        candidates=["vignetting", "tone", "noise"],
    )
    assert report.added == [] and report.accepted == []
    assert report.gap_after == report.gap_before
    assert "No significant gap" in report.verdict or "Unexplained" in report.verdict


def _write_pairs(root: Path, pairs: list[tuple[torch.Tensor, torch.Tensor]]) -> None:
    for index, (clean, captured) in enumerate(pairs):
        for side, image in (("clean", clean), ("captured", captured)):
            write_image(image.mul(255).round().to(torch.uint8), root / side / f"{index:02d}.png")


def _cli(argv: list[str]) -> int:
    return main(["diagnose", *argv], prog="camdegrade")


@pytest.mark.slow
def test_cli_writes_json_html_and_profile(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    camera = _camera(Tone(gamma=1.25, black=0.02))
    _write_pairs(tmp_path / "pairs", _pairs(camera, 16, 48, seed=7))
    CameraProfile(None, [], name="identity").save(tmp_path / "p.safetensors")
    argv = [str(tmp_path / "p.safetensors"), str(tmp_path / "pairs"), "--json", str(tmp_path / "r.json")]
    argv += ["--html", str(tmp_path / "r.html"), "--out-profile", str(tmp_path / "p2.safetensors")]
    assert _cli([*argv, "--candidates", "tone", "vignetting", "--quiet"]) == 0
    data = json.loads((tmp_path / "r.json").read_text())
    assert data["added"] and data["added"][0] == "tone"
    assert "calibration" in data["split"] and "held-out" in data["split"]
    assert (tmp_path / "r.html").is_file()
    assert load_profile(tmp_path / "p2.safetensors").effect_names == data["added"]
    assert "closes" in capsys.readouterr().out


def test_cli_writes_the_profile_after_a_removal(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A vignetting stage the camera lacks: ``remove vignetting`` is accepted and --out-profile has it removed (a
    removal adds nothing, and is still a change worth writing)."""
    _write_pairs(tmp_path / "pairs", _pairs(_camera(Tone(gamma=1.2)), 16, 48, seed=5))
    CameraProfile(None, [Vignetting(k1=-0.4), Tone(gamma=1.2)], name="vignetted").save(tmp_path / "p.safetensors")
    argv = [str(tmp_path / "p.safetensors"), str(tmp_path / "pairs"), "--json", str(tmp_path / "r.json")]
    argv += ["--out-profile", str(tmp_path / "p2.safetensors"), "--kinds", "remove", "--no-critic", "--quiet"]
    assert _cli(argv) == 0
    data = json.loads((tmp_path / "r.json").read_text())
    assert data["accepted"] == ["remove vignetting"] and data["added"] == [] and data["critic"] == {}
    assert {change["kind"] for change in data["changes"]} == {"remove"}
    assert load_profile(tmp_path / "p2.safetensors").effect_names == ["tone"]
    assert "(remove vignetting)" in capsys.readouterr().out


def test_cli_rejects_an_unknown_kind_before_loading(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert _cli(["city100-iphonex", str(tmp_path / "absent"), "--kinds", "remove", "shrink"]) == 1
    error = capsys.readouterr().err
    assert "kinds must be one or more of ['add', 'remove', 'refit', 'network'], got ['remove', 'shrink']" in error
    assert error.count("\n") == 1


def test_cli_rejects_a_bad_profile_suffix(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert _cli(["city100-iphonex", str(tmp_path), "--out-profile", str(tmp_path / "p.pt")]) == 1
    error = capsys.readouterr().err
    assert re.search(r"--out-profile must end in \.safetensors", error) and error.count("\n") == 1


def test_unpaired_mode(tmp_path: Path) -> None:
    camera = _camera(Noise(a=0.01))
    pairs = _pairs(camera, 8, 48, seed=9)
    for index, (clean, captured) in enumerate(pairs):
        write_image(clean.mul(255).round().to(torch.uint8), tmp_path / "clean" / f"{index}.png")
        write_image(captured.mul(255).round().to(torch.uint8), tmp_path / "real" / f"{index}.png")
    CameraProfile(None, []).save(tmp_path / "p.safetensors")
    out = tmp_path / "u.json"
    argv = [str(tmp_path / "p.safetensors"), str(tmp_path / "clean"), "--real", str(tmp_path / "real")]
    assert _cli([*argv, "--json", str(out), "--quiet"]) == 0
    data = json.loads(out.read_text())
    assert data["mode"] == "unpaired" and data["added"] == [] and data["effects"] == []
    assert data["where"][0]["axis"] in ("noise", "spectrum", "blocks")


def test_a_critic_with_one_answer_scores_chance_and_says_so() -> None:
    from camdegrade.measures.critic import CriticNet, Patches, score

    images = _content(3, 64, seed=5)
    sims = [image.clamp(0.01, 0.99) for image in images]
    patches = Patches.sample(images, images, sims, seed=0, stream="test")
    net = CriticNet().eval()
    torch.nn.init.zeros_(net.head.weight)
    torch.nn.init.constant_(net.head.bias, 1.0)  # "real" for everything
    result = score(net, patches, seed=0)
    assert result.one_answer and result.accuracy == result.low == result.high == 0.5
    assert "same answer for every patch" in result.describe()
    torch.nn.init.ones_(net.head.weight)
    torch.nn.init.zeros_(net.head.bias)
    with torch.no_grad():
        torch.nn.init.constant_(net.head.bias, -float(net(patches.inputs).median()))  # about half each way
    assert not score(net, patches, seed=0).one_answer


@pytest.mark.slow
def test_captures_identical_to_the_clean_images_say_the_profile_degrades_more() -> None:
    """Issue 26: a camera that changes nothing, a profile (network and effects) that degrades a lot. No single change
    closes the gap, but the verdict must not call it unexplained: the profile degrades more than the camera."""
    pairs = [(clean, clean.clone()) for clean in _content(16, 64, seed=5)]
    report = diagnose(load_profile(PAPER_BUILT_IN), pairs[:8], held_out=pairs[8:], candidates=["tone"], critic=False)
    assert report.accepted == []
    assert report.verdict.startswith("The profile degrades more than the camera"), report.verdict
    assert "Unexplained" not in report.verdict


def test_flat_images_with_a_colour_offset_are_explained_by_colour_and_say_what_cannot_be_measured() -> None:
    """Issue 26: flat constant images, the captures differing only by a colour offset. The statistics that need
    texture (transfer, block edges, displacement) or noise (its correlation) must say they cannot be measured rather
    than report float rounding as a finding, and a colour change must explain the offset."""
    generator = torch.Generator().manual_seed(0)
    offset = torch.tensor([12.0, -8.0, 10.0])[:, None, None] / 255
    pairs = []
    for _ in range(16):
        clean = ((torch.rand(3, 1, 1, generator=generator) * 0.6 + 0.2).expand(3, 64, 64) * 255).round() / 255
        pairs.append((clean, ((clean + offset).clamp(0, 1) * 255).round() / 255))
    report = diagnose(
        CameraProfile(None, []), pairs[:8], held_out=pairs[8:], candidates=["jpeg", "color", "tone"], critic=False
    )
    assert report.accepted and report.accepted[0] in ("add color", "add tone"), report.verdict
    assert "add jpeg" not in report.accepted
    where = {entry["axis"]: entry for entry in report.where}
    for axis in ("frequency", "blocks", "alignment", "noise_correlation"):
        assert "not measurable" in where[axis]["finding"], where[axis]
        assert not where[axis]["significant"]
    assert where["spatial"]["significant"] and "R +12.0, G -8.0, B +10.0" in where["spatial"]["finding"]
