"""The sim-to-real diagnosis: gap fairness, attribution on a withheld effect, control, JSON schema, HTML, CLI."""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import pytest
import torch

from camdegrade.diagnose import DiagnosisReport, diagnose
from camdegrade.diagnose.attribute import HeldOut, simulate, split_pairs
from camdegrade.diagnose.cli import add_diagnose_parser, run_diagnose
from camdegrade.diagnose.report import REQUIRED_KEYS
from camdegrade.diagnose.stats import FAMILIES, gap
from camdegrade.effects import EFFECTS, JPEG, Noise, Tone, Vignetting
from camdegrade.io import write_image
from camdegrade.profile import CameraProfile, load_profile
from camdegrade.sim import VirtualCamera
from effects_images import patch_chart, photo

torch.set_num_threads(1)


def _content(count: int, size: int, seed: int) -> list[torch.Tensor]:
    """Photo crops and patch charts (flat areas at many intensities), different per seed."""
    generator = torch.Generator().manual_seed(seed)
    names = ("astronaut", "coffee", "chelsea")
    images = []
    for index in range(count):
        if index % 3 == 2:
            images.append(patch_chart(size, patches=6, seed=seed * 100 + index))
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
    held = HeldOut.build(_pairs(camera, 12, 64, seed=3), seed=0)
    without, _ = held.statistics(CameraProfile(None, [Tone(gamma=1.1)]))
    correct, sims = held.statistics(CameraProfile(None, [Noise(a=0.004, b=1e-5), Tone(gamma=1.1)]))
    assert gap(held.real, correct) < 0.5 * gap(held.real, without)
    mse_without = sum(
        float((s - r).pow(2).mean())
        for s, r in zip(simulate(CameraProfile(None, [Tone(gamma=1.1)]), held.cleans, 0), held.reals, strict=True)
    )
    mse_correct = sum(float((s - r).pow(2).mean()) for s, r in zip(sims, held.reals, strict=True))
    assert mse_correct > mse_without  # why paired MSE cannot be the measure


def test_split_keeps_scenes_apart() -> None:
    scenes = ["a", "a", "b", "b", "c", "d", "e", "e"]
    calibration, held_out = split_pairs(scenes, 0.5, seed=0)
    assert sorted(calibration + held_out) == list(range(len(scenes)))
    assert not {scenes[i] for i in calibration} & {scenes[i] for i in held_out}
    assert calibration and held_out


@pytest.fixture(scope="module")
def vignetting_report() -> DiagnosisReport:
    camera = _camera(Vignetting(k1=-0.35), Noise(a=0.002), JPEG(quality=80))
    profile = CameraProfile(None, [Noise(a=0.002), JPEG(quality=80)], name="no-vignetting")
    calibration = _pairs(camera, 16, 64, seed=0)
    held_out = _pairs(camera, 16, 64, seed=1)
    return diagnose(profile, calibration, held_out=held_out, candidates=["vignetting", "tone", "blur", "noise"])


def test_withheld_vignetting_is_named_and_closes_the_gap(vignetting_report: DiagnosisReport) -> None:
    report = vignetting_report
    assert report.added[0] == "vignetting"
    assert report.effects[0]["name"] == "vignetting"
    assert report.fraction_closed >= 0.7
    assert report.gap_after < report.gap_before
    k1 = report.fitted_params["vignetting"]["k1"]
    assert k1 == pytest.approx(-0.35, rel=0.25)
    assert report.where[0]["axis"] in ("spatial", "intensity", "color")
    assert report.profile is not None and "vignetting" in report.profile.effect_names


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


def test_html_is_one_self_contained_file(vignetting_report: DiagnosisReport, tmp_path: Path) -> None:
    page = vignetting_report.write_html(tmp_path / "r.html").read_text()
    assert page.startswith("<!DOCTYPE html>")
    assert vignetting_report.verdict.split(":")[0] in page
    assert page.index("class='verdict'") < page.index("<h2>")  # verdict first
    assert not re.search(r"(src|href)\s*=\s*['\"](?!data:)", page)
    assert "<link" not in page and "<script" not in page and "@import" not in page and "url(" not in page
    assert "data:image/png;base64," in page


def test_control_names_nothing() -> None:
    camera = _camera(Vignetting(k1=-0.2), Noise(a=0.002))
    profile = CameraProfile(None, [Vignetting(k1=-0.2), Noise(a=0.002)])
    report = diagnose(
        profile,
        _pairs(camera, 12, 64, seed=5),
        held_out=_pairs(camera, 12, 64, seed=6),
        candidates=["vignetting", "tone", "noise"],
    )
    assert report.added == []
    assert report.gap_after == report.gap_before
    assert "No significant gap" in report.verdict or "Unexplained" in report.verdict


def _write_pairs(root: Path, pairs: list[tuple[torch.Tensor, torch.Tensor]]) -> None:
    for index, (clean, captured) in enumerate(pairs):
        for side, image in (("clean", clean), ("captured", captured)):
            write_image(image.mul(255).round().to(torch.uint8), root / side / f"{index:02d}.png")


def _cli(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="camdegrade")
    add_diagnose_parser(parser.add_subparsers(dest="command"))
    return run_diagnose(parser.parse_args(["diagnose", *argv]))


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


def test_cli_rejects_a_bad_profile_suffix(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"--out-profile must end in \.safetensors"):
        _cli(["city100-iphonex", str(tmp_path), "--out-profile", str(tmp_path / "p.pt")])


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
