"""The command line under bad input (issue 17): one line on stderr and a non-zero status for every user error of
every subcommand, inputs never overwritten, and one unreadable file never stops a batch."""

from __future__ import annotations

import os
import re
from collections.abc import Callable
from pathlib import Path

import pytest
import torch

import camdegrade.fitting.steps.network as network_step
from bad_inputs import animated, cut_image, good_image, one_line_error, png_with_rows, profile_file, run_cli
from camdegrade.io import read_image
from profiles_for_tests import deterministic_profile, stochastic_profile
from test_fit import QUICK, make_pairs_folder

BIG_SEED = str(2**70)


@pytest.fixture
def profile_path(tmp_path: Path) -> Path:
    return stochastic_profile().save(tmp_path / "cam.safetensors")


def _images(folder: Path, count: int, prefix: str = "good") -> list[Path]:
    return [good_image(folder / f"{prefix}{index}.png", seed=index) for index in range(count)]


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(path.relative_to(folder)): path.read_bytes() for path in sorted(folder.rglob("*")) if path.is_file()}


# --- every subcommand: one line on stderr, non-zero status -------------------------------------------------------

Case = Callable[[Path, Path], list]


def _folder(folder: Path) -> Path:
    _images(folder, 4)
    return folder


def _two_pairs(tmp: Path) -> Path:
    return make_pairs_folder(tmp / "two", count=2)


def _apply_option(option: str, value: str) -> Case:
    """``apply`` of the profile to one good image with ``option value``."""
    return lambda tmp, p: ["apply", p, good_image(tmp / "a.png"), tmp / "o.png", option, value]


def _fit_option(option: str, value: str) -> Case:
    """``fit`` of the temporary folder with ``option value``: a usage error, found before any pair is read."""
    return lambda tmp, p: ["fit", tmp, "-o", tmp / "x.safetensors", option, value]


CASES: dict[str, tuple[Case, int, str]] = {
    "list with an argument": (lambda tmp, p: ["list", "everything"], 2, r"unrecognized arguments: everything"),
    "apply --threads 0": (_apply_option("--threads", "0"), 2, r"--threads: must be an integer >= 1, got 0"),
    "info /dev/zero": (lambda tmp, p: ["info", "/dev/zero"], 1, r"'/dev/zero' is not a regular file"),
    "info a profile asking for a huge network": (
        lambda tmp, p: [
            "info",
            profile_file(
                tmp / "w.safetensors",
                deterministic_profile(),
                {"network": {"arch": "DomainShiftNet", "config": {"width": 10**6}}},
            ),
        ],
        1,
        r"width must be an integer from 1 to 1024",
    ),
    "apply a bomb": (
        lambda tmp, p: ["apply", p, png_with_rows(tmp / "bomb.png", 12000, 12000, 50), tmp / "o.png"],
        1,
        r"bomb\.png.*144000000 pixels",
    ),
    "apply --device meta": (_apply_option("--device", "meta"), 2, "meta"),
    "apply --p 2": (_apply_option("--p", "2"), 2, r"--p: must be a probability from 0 to 1, got 2"),
    "apply --seed 2**70": (_apply_option("--seed", BIG_SEED), 2, rf"--seed: .*got {BIG_SEED}"),
    "apply x.png x.png": (
        lambda tmp, p: ["apply", p, good_image(tmp / "x.png"), tmp / "x.png"],
        1,
        r"is the input file itself",
    ),
    "simulate --max-side 0": (
        lambda tmp, p: ["simulate", "lowcost-robot", good_image(tmp / "a.png"), tmp / "out", "--max-side", "0"],
        2,
        r"--max-side: must be an integer >= 1, got 0",
    ),
    "simulate --seed 2**70": (
        lambda tmp, p: ["simulate", "lowcost-robot", good_image(tmp / "a.png"), tmp / "out", "--seed", BIG_SEED],
        2,
        r"--seed: ",
    ),
    "fit -o /proc/x.safetensors": (
        lambda tmp, p: ["fit", make_pairs_folder(tmp / "pairs"), "-o", "/proc/x.safetensors", *QUICK],
        1,
        r"cannot write '/proc/x\.safetensors'",
    ),
    "fit --epochs 0": (_fit_option("--epochs", "0"), 2, r"--epochs: must be an integer >= 1, got 0"),
    "fit --epochs -3": (_fit_option("--epochs", "-3"), 2, r"--epochs: must be an integer >= 1, got -3"),
    "fit --lr nan": (_fit_option("--lr", "nan"), 2, r"--lr: must be a finite"),
    "fit --val-fraction 1": (
        _fit_option("--val-fraction", "1"),
        2,
        r"--val-fraction: must be a fraction from 0 \(inclusive\) to 1 \(exclusive\), got 1",
    ),
    "diagnose --calibration-fraction 0": (
        lambda tmp, p: ["diagnose", p, tmp, "--calibration-fraction", "0"],
        2,
        r"--calibration-fraction: must be a fraction between 0 and 1 \(exclusive\), got 0",
    ),
    "fit --lr-halving-epochs with the fast recipe": (
        lambda tmp, p: ["fit", make_pairs_folder(tmp / "pairs"), "-o", tmp / "x.safetensors", "--lr-halving-epochs", 5],
        1,
        r"--lr-halving-epochs applies to --recipe paper or --schedule step",
    ),
    "fit --resume without a checkpoint": (
        lambda tmp, p: ["fit", make_pairs_folder(tmp / "pairs"), "-o", tmp / "x.safetensors", "--resume", *QUICK],
        1,
        r"--resume: checkpoint '.*x\.ckpt\.safetensors' does not exist",
    ),
    "distill --width 0": (lambda tmp, p: ["distill", p, "-o", tmp / "f.safetensors", "--width", "0"], 2, r"--width"),
    "distill a missing images folder": (
        lambda tmp, p: ["distill", p, "-o", tmp / "f.safetensors", "--images", tmp / "none"],
        1,
        r"images must be a folder of images, got '.*none'",
    ),
    "distill onto the teacher": (
        lambda tmp, p: ["distill", p, "-o", p],
        1,
        r"is the input file itself",
    ),
    "diagnose --max-pairs -2": (
        lambda tmp, p: ["diagnose", p, tmp, "--max-pairs", "-2"],
        2,
        r"--max-pairs: must be an integer >= 1, got -2",
    ),
    "diagnose --real --max-pairs -2": (
        lambda tmp, p: ["diagnose", p, _folder(tmp / "c"), "--real", _folder(tmp / "r"), "--max-pairs", "-2"],
        2,
        r"--max-pairs: must be an integer >= 1, got -2",
    ),
    "diagnose two pairs": (
        lambda tmp, p: ["diagnose", p, _two_pairs(tmp)],
        1,
        r"at least 4 calibration and 4 held-out pairs",
    ),
    "diagnose --seed 2**70": (lambda tmp, p: ["diagnose", p, tmp, "--seed", BIG_SEED], 2, r"--seed: "),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_every_subcommand_reports_bad_input_in_one_line(case: str, tmp_path: Path, profile_path: Path, capsys) -> None:
    build, status, message = CASES[case]
    argv = build(tmp_path, profile_path)
    capsys.readouterr()
    code, _, err = run_cli(argv, capsys)
    line = one_line_error(err)
    assert code == status, err
    assert line.startswith("camdegrade") and " error: " in line
    assert re.search(message, line), line


def test_the_case_table_covers_every_subcommand() -> None:
    from camdegrade.cli import _COMMANDS

    assert {case.split()[0] for case in CASES} == set(_COMMANDS)


# --- never overwrite an input ------------------------------------------------------------------------------------


@pytest.mark.parametrize("overwrite", [[], ["--overwrite"]])
def test_apply_never_writes_over_the_file_it_reads(tmp_path: Path, profile_path: Path, overwrite, capsys) -> None:
    source = good_image(tmp_path / "x.png")
    before = source.read_bytes()
    os.link(source, tmp_path / "hard.png")
    (tmp_path / "soft.png").symlink_to(source)
    for target in ("x.png", "hard.png", "soft.png", "./x.png"):
        code, _, err = run_cli(["apply", profile_path, source, tmp_path / target, *overwrite], capsys)
        assert code == 1 and "is the input file itself" in one_line_error(err)
    assert source.read_bytes() == before


@pytest.mark.parametrize("overwrite", [[], ["--overwrite"]])
def test_apply_refuses_the_input_folder_as_output(tmp_path: Path, profile_path: Path, overwrite, capsys) -> None:
    _images(tmp_path / "d", 2)
    before = _snapshot(tmp_path / "d")
    code, _, err = run_cli(["apply", profile_path, tmp_path / "d", tmp_path / "d", *overwrite], capsys)
    assert code == 1 and "is the input folder" in one_line_error(err)
    assert _snapshot(tmp_path / "d") == before


def test_apply_into_a_folder_inside_the_input_needs_overwrite(tmp_path: Path, profile_path: Path, capsys) -> None:
    _images(tmp_path / "d", 2)
    before = _snapshot(tmp_path / "d")
    argv = ["apply", profile_path, tmp_path / "d", tmp_path / "d" / "out"]
    code, _, err = run_cli(argv, capsys)
    assert code == 1 and "inside the input folder" in one_line_error(err) and "--overwrite" in err
    assert _snapshot(tmp_path / "d") == before
    for _ in range(2):  # a rerun does not degrade its own outputs
        code, _, err = run_cli([*argv, "--overwrite"], capsys)
        assert code == 0, err
    assert sorted(_snapshot(tmp_path / "d")) == ["good0.png", "good1.png", "out/good0.png", "out/good1.png"]


def test_simulate_never_writes_over_its_input(tmp_path: Path, capsys) -> None:
    source = good_image(tmp_path / "pairs" / "clean" / "a.png", size=(40, 40))
    before = source.read_bytes()
    for overwrite in ([], ["--overwrite"]):
        argv = ["simulate", "lowcost-robot", source, tmp_path / "pairs", "--max-side", "20", *overwrite]
        code, _, err = run_cli(argv, capsys)
        assert code == 1 and "is the input file itself" in one_line_error(err)
    assert source.read_bytes() == before


def test_simulate_into_its_input_folder_needs_overwrite(tmp_path: Path, capsys) -> None:
    _images(tmp_path / "d", 2)
    argv = ["simulate", "lowcost-robot", tmp_path / "d", tmp_path / "d" / "pairs"]
    code, _, err = run_cli(argv, capsys)
    assert code == 1 and "inside the input folder" in one_line_error(err)
    for _ in range(2):
        code, out, err = run_cli([*argv, "--overwrite"], capsys)
        assert code == 0, err
        assert "wrote 2 pair(s)" in out
    code, _, err = run_cli(["simulate", "lowcost-robot", tmp_path / "d", tmp_path / "d", "--overwrite"], capsys)
    assert code == 1 and "is the input folder" in one_line_error(err)


# --- one bad file never stops a batch ----------------------------------------------------------------------------


def _bad_files(folder: Path) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    not_an_image = folder / "notes.png"
    not_an_image.write_text("not an image")
    return [
        cut_image(folder / "cut.png"),
        png_with_rows(folder / "bomb.png", 12000, 12000, 50),
        png_with_rows(folder / "short.png", 64, 64, 8),
        animated(folder / "anim.webp"),
        not_an_image,
    ]


def test_apply_degrades_every_readable_image_and_reports_the_rest(tmp_path: Path, profile_path: Path, capsys) -> None:
    good = _images(tmp_path / "in", 4)
    bad = _bad_files(tmp_path / "in")
    code, out, err = run_cli(["apply", profile_path, tmp_path / "in", tmp_path / "out"], capsys)
    assert code == 1
    assert "5 of 9 image(s) could not be degraded" in one_line_error(err)
    assert sorted(path.name for path in (tmp_path / "out").iterdir()) == sorted(path.name for path in good)
    summary = out[out.index("could not be read") :]
    assert all(path.name in summary for path in bad)
    assert all(read_image(tmp_path / "out" / path.name).shape == (3, 24, 32) for path in good)


def test_simulate_writes_every_readable_pair_and_reports_the_rest(tmp_path: Path, capsys) -> None:
    _images(tmp_path / "in", 3)
    cut_image(tmp_path / "in" / "zz_cut.png")
    code, out, err = run_cli(["simulate", "lowcost-robot", tmp_path / "in", tmp_path / "pairs"], capsys)
    assert code == 1 and "1 of 4 image(s) could not be simulated" in one_line_error(err)
    assert sorted(path.name for path in (tmp_path / "pairs" / "captured").iterdir()) == [
        f"good{i}.png" for i in range(3)
    ]
    assert "zz_cut.png" in out[out.index("could not be read") :]


# --- checks that come before the work ----------------------------------------------------------------------------


def test_fit_checks_its_output_is_writable_before_training(tmp_path: Path, monkeypatch, capsys) -> None:
    def no_training(*args, **kwargs):
        raise AssertionError("trained before checking the output")

    monkeypatch.setattr(network_step, "fit_network", no_training)
    pairs = make_pairs_folder(tmp_path / "pairs")
    (tmp_path / "taken.safetensors").mkdir()
    good_image(tmp_path / "file.png")
    for output in ("/proc/x.safetensors", tmp_path / "taken.safetensors", tmp_path / "file.png" / "x.safetensors"):
        code, _, err = run_cli(["fit", pairs, "-o", output, *QUICK], capsys)
        assert code == 1 and "cannot write" in one_line_error(err)


def test_diagnose_checks_its_outputs_are_writable_before_diagnosing(tmp_path: Path, monkeypatch, capsys) -> None:
    import camdegrade.diagnose.core as core

    monkeypatch.setattr(core, "attribute", lambda *a, **k: pytest.fail("diagnosed before checking the outputs"))
    pairs = make_pairs_folder(tmp_path / "pairs", count=8)
    good_image(tmp_path / "file.png")
    code, _, err = run_cli(["diagnose", "city100-iphonex", pairs, "--json", tmp_path / "file.png" / "r.json"], capsys)
    assert code == 1 and "is a file, not a folder" in one_line_error(err)


def test_a_device_this_machine_lacks_is_a_usage_error(tmp_path: Path, profile_path: Path, capsys) -> None:
    if torch.backends.mps.is_available():
        pytest.skip("this machine has an MPS device")
    code, _, err = run_cli(
        ["apply", profile_path, good_image(tmp_path / "a.png"), tmp_path / "o.png", "--device", "mps"], capsys
    )
    assert code == 2 and "--device 'mps'" in one_line_error(err)


def test_an_input_that_is_a_device_is_not_read(tmp_path: Path, profile_path: Path, capsys) -> None:
    code, _, err = run_cli(["apply", profile_path, "/dev/zero", tmp_path / "o.png"], capsys)
    assert code == 1 and "'/dev/zero' is not a regular file or folder" in one_line_error(err)
