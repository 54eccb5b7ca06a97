"""Issue 26: a fit or a distillation that made things worse says so (stderr, metadata; ``--strict`` fails), and
the metadata stays strict JSON when a PSNR is infinite (identical images)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
import torch.nn.functional as F

from bad_inputs import one_line_error, run_cli
from camdegrade import load_profile
from camdegrade.fitting import FitConfig, distill_profile, fit_profile
from camdegrade.io import write_image
from camdegrade.synthetic import dead_leaves_images
from conftest import PAPER_BUILT_IN

QUICK = ["--epochs", "1", "--crop", "16", "--batch-size", "4", "--crops-per-pair", "2", "--quiet"]


def _pairs(root: Path, *, identical: bool, count: int = 6) -> Path:
    """Smooth clean images; captures equal to them, or half as bright (a network beats the identity in 2 epochs)."""
    generator = torch.Generator().manual_seed(0)
    for index in range(count):
        clean = F.interpolate(torch.rand(1, 3, 8, 8, generator=generator), size=(32, 32), mode="bilinear")[0]
        write_image(clean, root / "clean" / f"{index}.png")
        write_image(clean if identical else clean * 0.5, root / "captured" / f"{index}.png")
    return root


def _strict_metadata(path: Path) -> dict:
    """The profile file's metadata, parsed as strict JSON (``Infinity`` and ``NaN`` refused)."""

    def refuse(constant: str) -> None:
        raise ValueError(f"not strict JSON: {constant}")

    raw = path.read_bytes()
    header = json.loads(raw[8 : 8 + int.from_bytes(raw[:8], "little")], parse_constant=refuse)
    return {key: json.loads(value, parse_constant=refuse) for key, value in header["__metadata__"].items()}


def test_fit_on_identical_pairs_writes_strict_json_and_warns(tmp_path: Path, capsys) -> None:
    out = tmp_path / "same.safetensors"
    code, _, err = run_cli(["fit", _pairs(tmp_path / "pairs", identical=True), "-o", out, *QUICK], capsys)
    assert code == 0
    assert "warning: the fitted network is worse than the identity" in err
    metadata = next(iter(_strict_metadata(out).values()))
    assert metadata["quality"]["identity_psnr_db"] is None  # infinite: the captures are the clean images
    assert metadata["quality"]["network_psnr_db"] > 0
    assert "worse than the identity" in metadata["fitted"]["warnings"][0]
    assert load_profile(out).quality["identity_psnr_db"] is None


def test_fit_strict_writes_no_profile_worse_than_the_identity(tmp_path: Path, capsys) -> None:
    out = tmp_path / "same.safetensors"
    pairs = _pairs(tmp_path / "pairs", identical=True)
    code, _, err = run_cli(["fit", pairs, "-o", out, *QUICK, "--strict"], capsys)
    assert code == 1 and not out.exists()
    assert "worse than the identity" in one_line_error(err) and "not written (--strict)" in err


def test_a_fit_that_beats_the_identity_has_no_warning(tmp_path: Path) -> None:
    lines: list[str] = []
    recipe = FitConfig(epochs=2, crop=16, batch_size=4, crops_per_pair=4, val_fraction=0.34, lr=0.01)
    profile = fit_profile(_pairs(tmp_path / "pairs", identical=False), recipe, log=lines.append)
    assert profile.quality["network_psnr_db"] > profile.quality["identity_psnr_db"] + 3
    assert "warnings" not in profile.fitted and not any("warning" in line for line in lines)


@pytest.mark.parametrize("epochs, warned", [(1, True), (20, False)])
def test_a_student_further_from_its_teacher_than_the_clean_images_is_warned_about(epochs: int, warned: bool) -> None:
    lines: list[str] = []
    # without the pointwise curves: one epoch of a curved student already beats the clean images here
    recipe = FitConfig(
        epochs=epochs,
        crop=32,
        batch_size=4,
        crops_per_pair=2,
        patience=0,
        lr=0.01 if epochs > 1 else 0.003,
        curves="none",
    )
    student = distill_profile(
        PAPER_BUILT_IN, dead_leaves_images(6, 64, seed=1), width=8, recipe=recipe, log=lines.append
    )
    quality = student.quality
    assert (quality["student_vs_teacher_psnr_db"] < quality["identity_vs_teacher_psnr_db"]) == warned
    assert ("warnings" in student.fitted) == warned
    assert any("the student is far from its teacher" in line for line in lines) == warned


def test_distill_cli_warns_on_stderr_and_strict_writes_nothing(tmp_path: Path, capsys) -> None:
    images = tmp_path / "images"
    for index, image in enumerate(dead_leaves_images(6, 64, seed=1)):
        write_image(image, images / f"{index}.png")
    tiny = ["--width", "8", "--epochs", "1", "--crop", "32", "--batch-size", "4", "--crops-per-pair", "2", "--quiet"]
    tiny += ["--curves", "none"]  # as above: one epoch of a curved student is not far from its teacher
    out = tmp_path / "fast.safetensors"
    code, _, err = run_cli(["distill", PAPER_BUILT_IN, "-o", out, "--images", images, *tiny], capsys)
    assert code == 0 and out.exists()
    assert "camdegrade distill: warning: the student is far from its teacher" in err
    assert "far from its teacher" in load_profile(out).fitted["warnings"][0]
    strict = tmp_path / "strict.safetensors"
    code, _, err = run_cli(["distill", PAPER_BUILT_IN, "-o", strict, "--images", images, *tiny, "--strict"], capsys)
    assert code == 1 and not strict.exists() and "not written (--strict)" in one_line_error(err)
