"""``camdegrade fit --unpaired``: every option of ``fit`` is either passed on to
:func:`~camdegrade.fitting.unpaired.fit_unpaired` or refused by name (issue 44), checked from the parser's own option
list, so an option added to ``fit`` later cannot be silently ignored; ``--effects`` with a stage that needs
correspondence is refused with the API's message; ``--strict`` refuses unreadable files before fitting."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import pytest
import torch

from bad_inputs import good_image, one_line_error, run_cli
from camdegrade import CameraProfile
from camdegrade.cli import fit as fit_command
from camdegrade.cli import main_parser
from camdegrade.fitting.unpaired import MIN_IMAGES, UNPAIRED_EFFECTS

#: A value for every option of ``fit`` (by option string); a new option must be added here, and to the command's
#: table (``camdegrade.cli.fit.UNPAIRED_USES`` or ``UNPAIRED_REFUSES``).
SAMPLES: dict[str, list[str]] = {
    "--recipe": ["paper"],
    "--epochs": ["3"],
    "--crop": ["32"],
    "--batch-size": ["4"],
    "--lr": ["0.01"],
    "--lr-halving-epochs": ["5"],
    "--crops-per-pair": ["4"],
    "--seed": ["5"],
    "--schedule": ["step"],
    "--patience": ["2"],
    "--precision": ["float32"],
    "--width": ["16"],
    "--arch": ["paper"],
    "--upsample": ["smooth"],
    "--curves": ["none"],
    "--val-fraction": ["0.2"],
    "--effects": ["noise", "jpeg"],
    "--texture": ["none"],
    "--learned-texture": ["none"],
    "--jitter": ["none"],
    "--sensor-scale": ["0.5"],
    "--area-sensor": [],
    "--no-effects": [],
    "--device": ["cpu"],
    "--threads": ["2"],
    "--clean-suffix": ["_mean"],
    "--captured-suffix": ["_real"],
    "--max-pairs": ["9"],
    "--strict": [],
    "--align": [],
    "--size-mismatch": ["crop"],
    "--init-from": ["city100-iphonex"],
    "--checkpoint": ["other.ckpt.safetensors"],
    "--resume": [],
    "--name": ["cam"],
    "--description": ["a camera"],
    "--quiet": [],
}
#: What each used option becomes in the call (``threads``: torch's thread count during it).
PASSED: dict[str, tuple[str, Any]] = {
    "--seed": ("seed", 5),
    "--effects": ("effects", ["noise", "jpeg"]),
    "--learned-texture": ("effects", [name for name in UNPAIRED_EFFECTS if name != "learned_texture"]),
    "--sensor-scale": ("sensor_scale", 0.5),
    "--area-sensor": ("area_sensor", True),
    "--max-pairs": ("max_images", 9),
    "--strict": ("strict", True),
    "--threads": ("threads", 2),
    "--name": ("name", "cam"),
    "--description": ("description", "a camera"),
    "--quiet": ("progress", False),
    "--device": ("device", "cpu"),  # the only device it runs on: accepted, nothing to pass
    "--checkpoint": ("checkpoint", Path("other.ckpt.safetensors")),
    "--resume": ("resume", True),  # of the default checkpoint, which the test writes first
}
#: Options that are the command's own arguments, not options to pass or refuse.
ARGUMENTS = ("-h", "--help", "-o", "--output", "--unpaired", "--clean")


def _fit_options() -> list[argparse.Action]:
    commands = next(action for action in main_parser()._actions if isinstance(action, argparse._SubParsersAction))
    return [action for action in commands.choices["fit"]._actions if action.option_strings]


def _options() -> list[str]:
    return [action.option_strings[-1] for action in _fit_options() if action.option_strings[-1] not in ARGUMENTS]


@pytest.fixture
def recorded(monkeypatch: pytest.MonkeyPatch) -> list[dict[str, Any]]:
    """``fit_unpaired`` replaced by a recorder returning an empty profile (the options are under test, not the fit)."""
    calls: list[dict[str, Any]] = []

    def fake(captured, clean=None, **options: Any) -> CameraProfile:
        calls.append({"captured": captured, "clean": clean, "threads": torch.get_num_threads(), **options})
        profile = CameraProfile(None, [])
        profile.fitted = {"unpaired": True}
        return profile

    monkeypatch.setattr("camdegrade.fitting.unpaired.fit_unpaired", fake)
    return calls


def _command(tmp_path: Path, *extra: str) -> list[str]:
    return [
        "fit",
        "--unpaired",
        str(tmp_path / "cap"),
        "--clean",
        str(tmp_path / "clean"),
        "-o",
        str(tmp_path / "p.safetensors"),
        *extra,
    ]


def test_every_option_of_fit_is_either_used_or_refused_by_the_unpaired_fit() -> None:
    dests = {action.option_strings[-1]: action.dest for action in _fit_options()}
    for option in _options():
        assert option in SAMPLES, f"{option}: new option of fit; add a sample value and decide what --unpaired does"
        dest = dests[option]
        assert (dest in fit_command.UNPAIRED_USES) != (dest in fit_command.UNPAIRED_REFUSES), option


@pytest.mark.parametrize("option", [option for option in SAMPLES if option in PASSED])
def test_an_option_the_unpaired_fit_uses_reaches_it(
    option: str, tmp_path: Path, recorded: list[dict[str, Any]], capsys: pytest.CaptureFixture
) -> None:
    default_checkpoint = tmp_path / "p.ckpt.safetensors"
    if option == "--resume":
        default_checkpoint.write_bytes(b"an earlier fit's")
    code, _, err = run_cli(_command(tmp_path, option, *SAMPLES[option]), capsys)
    assert code == 0, err
    assert not default_checkpoint.exists()  # removed once the profile is written
    ((keyword, value),) = [PASSED[option]]
    if keyword != "device":
        assert recorded[0][keyword] == value, recorded
    assert (tmp_path / "p.safetensors").is_file()


def test_left_out_the_options_keep_the_unpaired_defaults(
    tmp_path: Path, recorded: list[dict[str, Any]], capsys: pytest.CaptureFixture
) -> None:
    from camdegrade.fitting.unpaired import UNPAIRED_EFFECTS

    code, _, err = run_cli(_command(tmp_path), capsys)
    assert code == 0, err
    call = recorded[0]
    assert call["effects"] == UNPAIRED_EFFECTS and call["seed"] == 0 and call["sensor_scale"] == "auto"
    assert call["area_sensor"] is False
    assert call["max_images"] is None and call["strict"] is False and call["name"] == "p"
    assert call["checkpoint"] == tmp_path / "p.ckpt.safetensors" and call["resume"] is False


@pytest.mark.parametrize("option", [option for option in _options() if option not in PASSED])
def test_an_option_the_unpaired_fit_does_not_use_is_refused_by_name(
    option: str, tmp_path: Path, recorded: list[dict[str, Any]], capsys: pytest.CaptureFixture
) -> None:
    code, _, err = run_cli(_command(tmp_path, option, *SAMPLES[option]), capsys)
    line = one_line_error(err)
    assert code == 1 and f"{option} " in line and "not used with --unpaired" in line, line
    assert recorded == [] and not (tmp_path / "p.safetensors").exists()


def test_a_device_other_than_the_cpu_is_refused(
    tmp_path: Path, recorded: list[dict[str, Any]], capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(
        "camdegrade._runtime.device.check_device", lambda device, name="device": device
    )  # as if it existed
    code, _, err = run_cli(_command(tmp_path, "--device", "cuda:0"), capsys)
    assert code == 1 and "--device cuda:0 is not used with --unpaired" in one_line_error(err) and recorded == []


def _folder(folder: Path, count: int = MIN_IMAGES, side: int = 32) -> Path:
    for index in range(count):
        good_image(folder / f"{index:02d}.png", (side, side), seed=index)
    return folder


@pytest.mark.parametrize("name", ["misalignment", "distortion", "chromatic_aberration"])
def test_effects_that_need_correspondence_are_refused_with_the_api_message(
    name: str, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    captured = _folder(tmp_path / "cap")
    output = tmp_path / "p.safetensors"
    code, _, err = run_cli(["fit", "--unpaired", captured, "-o", output, "--effects", "noise", name], capsys)
    assert code == 1 and f"effects: {name!r} cannot be fitted unpaired" in one_line_error(err)
    assert not output.exists()


def test_strict_refuses_an_unreadable_file_before_fitting_and_writes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    captured = _folder(tmp_path / "cap")
    (captured / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\nnot an image")
    output = tmp_path / "p.safetensors"
    code, out, err = run_cli(["fit", "--unpaired", captured, "-o", output, "--strict", "--quiet"], capsys)
    line = one_line_error(err)
    assert code == 1 and "captured: 1 file(s) could not be used (strict" in line, line
    assert "broken.png" in out and not output.exists()


@pytest.mark.parametrize(("option", "value"), [("--area-sensor", []), ("--clean", ["clean"])])
def test_an_unpaired_only_option_with_pairs_is_refused_in_one_line(
    option: str, value: list[str], tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    code, _, err = run_cli(
        ["fit", str(tmp_path / "pairs"), "-o", str(tmp_path / "p.safetensors"), option, *value], capsys
    )
    line = one_line_error(err)
    assert code == 1 and f"{option} goes with --unpaired" in line, line
    assert not (tmp_path / "p.safetensors").exists()
