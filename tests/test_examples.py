"""``examples/`` is for users: at most six scripts, each on public names only (no ``_``-prefixed module or name of
camdegrade), and each runs. The research scripts behind docs/results.md live in ``experiments/``."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from camdegrade import load_profile
from conftest import REPOSITORY, load_script

EXAMPLES = sorted((REPOSITORY / "examples").glob("*.py"))
USER_SCRIPTS = {"demo", "fit_camera", "diagnose_camera", "fit_unpaired", "train_classifier", "lightning_datamodule"}


def _private_uses(source: str) -> list[str]:
    """Every import of a ``_``-prefixed camdegrade module or name, and every ``camdegrade._x`` attribute."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "camdegrade":
            parts = node.module.split(".") + [alias.name for alias in node.names]
            found += [f"from {node.module} import {alias.name}" for alias in node.names if _private(parts)]
        elif isinstance(node, ast.Import):
            names = [alias.name for alias in node.names if alias.name.split(".")[0] == "camdegrade"]
            found += [name for name in names if _private(name.split("."))]
        elif isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "camdegrade":
            found += [f"camdegrade.{node.attr}"] if _private([node.attr]) else []
    return found


def _private(parts: list[str]) -> bool:
    return any(part.startswith("_") and not part.startswith("__") for part in parts)


def test_examples_are_the_six_scripts_for_users() -> None:
    assert {path.stem for path in EXAMPLES} == USER_SCRIPTS


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda path: path.name)
def test_examples_use_public_names_only(path: Path) -> None:
    assert _private_uses(path.read_text()) == []


def test_the_import_check_can_fail() -> None:
    assert _private_uses(
        "from camdegrade._support.pixels import as_unit\nfrom camdegrade.io import _x\nimport camdegrade._support.seeds"
    ) == [
        "from camdegrade._support.pixels import as_unit",
        "from camdegrade.io import _x",
        "camdegrade._support.seeds",
    ]
    assert _private_uses("import camdegrade\ncamdegrade._LAZY\nfrom camdegrade.fitting import fit_profile") == [
        "camdegrade._LAZY"
    ]


def test_the_demo_prints_the_summary_and_writes_the_grid(tmp_path: Path, capsys) -> None:
    demo = load_script("examples/demo.py", "camdegrade_example_demo")
    assert demo.main(["--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out.splitlines()
    summary = out[: out.index("")]  # then one line per image
    assert summary[0] == "profile    city100-iphonex" and len(summary) <= 25 and max(map(len, summary)) <= 120
    held_out = "held-out   16 pairs: PSNR identity 23.79 dB -> profile 31.09 dB mean, 27.94 dB sampled"
    assert any(line.startswith(held_out) for line in summary)
    assert (tmp_path / "grid.png").is_file() and (tmp_path / "summary.json").is_file()


@pytest.mark.slow
def test_fit_camera_fits_a_virtual_cameras_pairs(tmp_path: Path, capsys) -> None:
    example = load_script("examples/fit_camera.py", "camdegrade_example_fit_camera")
    output = tmp_path / "cam.safetensors"
    assert example.main(["--demo", "-o", str(output), "--demo-pairs", "8", "--demo-size", "64", "--epochs", "1"]) == 0
    out = capsys.readouterr().out
    assert "profile    cam" in out and "8 pairs found" in out and "CameraDegrade(" in out
    profile = load_profile(output)
    assert profile.network is not None and profile.fitted["pairs"] == 8


@pytest.mark.slow
def test_diagnose_camera_finds_the_missing_blur(tmp_path: Path, capsys) -> None:
    example = load_script("examples/diagnose_camera.py", "camdegrade_example_diagnose_camera")
    html, output = tmp_path / "report.html", tmp_path / "fixed.safetensors"
    argv = ["--demo", "--demo-pairs", "12", "--demo-size", "96", "--no-critic", "--html", str(html), "-o", str(output)]
    assert example.main(argv) == 0
    assert "accepted: add blur" in capsys.readouterr().out
    assert html.is_file() and [effect.name for effect in load_profile(output).effects] == ["blur", "noise"]


@pytest.mark.slow
def test_fit_unpaired_fits_a_known_camera_from_its_photos(tmp_path: Path, capsys) -> None:
    example = load_script("examples/fit_unpaired.py", "camdegrade_example_fit_unpaired")
    output = tmp_path / "cam.safetensors"
    assert example.main(["--demo", "-o", str(output), "--demo-images", "8"]) == 0
    assert "fit        unpaired: 8 captures, 8 clean images" in capsys.readouterr().out
    profile = load_profile(output)
    assert profile.network is None and "blur" in [effect.name for effect in profile.effects]
