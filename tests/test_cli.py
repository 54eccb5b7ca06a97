"""The command line, called through main(argv) as pypa/build's tests do."""

from __future__ import annotations

import subprocess
import sys

import pytest
import torch

from camdegrade.cli import main
from camdegrade.io import read_image, write_image
from profiles_for_tests import deterministic_profile, stochastic_profile


@pytest.fixture
def profile_path(tmp_path):
    return stochastic_profile().save(tmp_path / "cam.safetensors")


def write_test_images(folder, names):
    generator = torch.Generator().manual_seed(0)
    for name in names:
        write_image(torch.randint(0, 256, (3, 14, 18), dtype=torch.uint8, generator=generator), folder / name)


def test_apply_file(tmp_path, profile_path, capsys):
    write_test_images(tmp_path, ["in.png"])
    assert main(["apply", str(profile_path), str(tmp_path / "in.png"), str(tmp_path / "out.png"), "--seed", "1"]) == 0
    out = read_image(tmp_path / "out.png")
    assert out.shape == (3, 14, 18) and not torch.equal(out, read_image(tmp_path / "in.png"))
    assert "degraded 1 image(s)" in capsys.readouterr().out


def test_apply_folder_recursively_keeps_relative_names_and_is_seeded(tmp_path, profile_path):
    write_test_images(tmp_path / "in", ["a.png", "sub/b.PNG", "sub/deeper/c.jpg"])
    (tmp_path / "in" / "notes.txt").write_text("not an image")
    for run in ("out1", "out2"):
        assert main(["apply", str(profile_path), str(tmp_path / "in"), str(tmp_path / run), "--seed", "3"]) == 0
    made = sorted(p.relative_to(tmp_path / "out1").as_posix() for p in (tmp_path / "out1").rglob("*") if p.is_file())
    assert made == ["a.png", "sub/b.PNG", "sub/deeper/c.jpg"]
    for name in made:
        assert (tmp_path / "out1" / name).read_bytes() == (tmp_path / "out2" / name).read_bytes()


def test_info_lists_the_chain(profile_path, capsys):
    assert main(["info", str(profile_path)]) == 0
    out = capsys.readouterr().out
    assert "test-stochastic" in out and "test_additive_noise [sensor]" in out


def test_list_names_built_ins(capsys):
    assert main(["list"]) == 0
    assert "city100-iphonex" in capsys.readouterr().out


@pytest.mark.parametrize(
    "argv, message",
    [
        (["info", "no-such-camera"], "neither an existing file nor a built-in profile"),
        (["apply", "no-such-camera", "a.png", "b.png"], "built-in profiles:"),
    ],
)
def test_user_errors_are_one_line_without_traceback(argv, message, capsys):
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_missing_input(tmp_path, profile_path, capsys):
    assert main(["apply", str(profile_path), str(tmp_path / "nope.png"), str(tmp_path / "o.png")]) == 1
    assert "does not exist" in capsys.readouterr().err


def test_pickle_profile_is_refused(tmp_path, capsys):
    torch.save({"w": torch.zeros(1)}, tmp_path / "m.pth")
    assert main(["info", str(tmp_path / "m.pth")]) == 1
    assert "never unpickles" in capsys.readouterr().err


def test_argparse_errors_exit_2(capsys):
    with pytest.raises(SystemExit) as info:
        main(["apply"])
    assert info.value.code == 2


def test_python_dash_m(tmp_path):
    path = deterministic_profile().save(tmp_path / "net.safetensors")
    result = subprocess.run(
        [sys.executable, "-m", "camdegrade", "info", str(path)], capture_output=True, text=True, check=False
    )
    assert result.returncode == 0, result.stderr
    assert "test-deterministic" in result.stdout


def test_unknown_preset_is_one_line(tmp_path, capsys):
    write_test_images(tmp_path / "in", ["a.png"])
    assert main(["simulate", "webcam", str(tmp_path / "in"), str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert "unknown preset 'webcam'; known presets:" in err and "Traceback" not in err


@pytest.mark.parametrize("device, message", [("nonsense", "must be a torch device"), ("cuda:7", "CUDA")])
def test_bad_device_is_a_usage_error(tmp_path, profile_path, device, message, capsys):
    if device.startswith("cuda") and torch.cuda.is_available():
        pytest.skip("a CUDA device is available here")
    with pytest.raises(SystemExit) as info:
        main(["apply", str(profile_path), "a.png", "b.png", "--device", device])
    assert info.value.code == 2 and message in capsys.readouterr().err
