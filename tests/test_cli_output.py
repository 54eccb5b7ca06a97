"""Issue 26: what the CLI prints is safe and quiet: names from files escaped (no screen clearing, no forged lines),
a reader that stops reading (``| head -1``, ``| true``) ends the command silently with status 0, and an empty
profile name is refused as such."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from bad_inputs import run_cli
from camdegrade._support.text import printable
from camdegrade.io import write_image
from camdegrade.pairs.discovery import discover_pairs
from profiles_for_tests import deterministic_profile

SOURCE = Path(__file__).resolve().parents[1] / "src"
FORGED = "\x1b[2J\x1b[Hforged: line\u202e"


def _cli(shell_tail: str, *argv: str) -> subprocess.CompletedProcess:
    """``python -m camdegrade ARGV | SHELL_TAIL`` in bash; stdout is the status of the camdegrade process."""
    command = " ".join([sys.executable, "-m", "camdegrade", *argv])
    script = f'{command} | {shell_tail}; echo "status=${{PIPESTATUS[0]}}"'
    env = {**os.environ, "PYTHONPATH": f"{SOURCE}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    return subprocess.run(["bash", "-c", script], capture_output=True, text=True, env=env, check=False, timeout=120)


@pytest.mark.parametrize(
    "argv, tail", [(("list",), "head -1"), (("info", "city100-iphonex"), "true"), (("--help",), "true")]
)
def test_a_reader_that_stops_reading_ends_the_command_quietly(argv: tuple[str, ...], tail: str) -> None:
    run = _cli(tail, *argv)
    assert run.stdout.strip().endswith("status=0"), run
    assert run.stderr == ""


def test_stdout_closed_before_the_first_write_is_quiet() -> None:
    """The reader gone before anything is written (deterministic, unlike a race with ``head``)."""
    env = {**os.environ, "PYTHONPATH": f"{SOURCE}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    command = [sys.executable, "-m", "camdegrade", "info", "city100-iphonex"]
    with subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env) as process:
        assert process.stdout is not None and process.stderr is not None
        process.stdout.close()
        err = process.stderr.read()
        status = process.wait(timeout=120)
    assert status == 0 and err == b""


def test_info_of_an_empty_name_says_so(capsys) -> None:
    code, _, err = run_cli(["info", ""], capsys)
    assert code == 2 and "empty profile name" in err and "is a folder" not in err


def _hostile_profile(path: Path) -> Path:
    """A profile file whose name and description hold escape sequences, a newline and a right-to-left override."""
    deterministic_profile().save(path)
    raw = path.read_bytes()
    length = int.from_bytes(raw[:8], "little")
    header = json.loads(raw[8 : 8 + length])
    metadata = json.loads(header["__metadata__"]["camdegrade"])
    metadata["name"], metadata["description"] = f"cam{FORGED}", f"desc\n{FORGED}"
    header["__metadata__"]["camdegrade"] = json.dumps(metadata)
    encoded = json.dumps(header).encode()
    encoded += b" " * (-len(encoded) % 8)
    path.write_bytes(len(encoded).to_bytes(8, "little") + encoded + raw[8 + length :])
    return path


def _assert_safe(text: str) -> None:
    assert "\x1b" not in text and "\u202e" not in text
    assert not any(line.startswith("forged") for line in text.splitlines()), text


def test_info_shows_hostile_names_escaped(tmp_path: Path, capsys) -> None:
    code, out, err = run_cli(["info", _hostile_profile(tmp_path / "cam.safetensors")], capsys)
    _assert_safe(out + err)
    assert code == 0, err
    assert "profile    cam\\x1b[2J\\x1b[Hforged: line\\u202e" in out
    assert "           desc\\n\\x1b[2J" in out
    code, out, err = run_cli(["info", _hostile_profile(tmp_path / "cam.safetensors"), "--json"], capsys)
    _assert_safe(out + err)
    assert code == 0 and json.loads(out)["name"] == f"cam{FORGED}"  # JSON escapes it, and reads back as written


def test_apply_lists_hostile_file_names_escaped(tmp_path: Path, capsys) -> None:
    folder = tmp_path / "in"
    write_image(torch.zeros(3, 16, 16, dtype=torch.uint8), folder / f"a{FORGED}.png")
    (folder / f"b\n{FORGED}.png").write_bytes(b"not a png")
    profile = deterministic_profile().save(tmp_path / "cam.safetensors")
    code, out, err = run_cli(["apply", profile, folder, tmp_path / "out"], capsys)
    assert code == 1  # the unreadable one is listed at the end
    _assert_safe(out + err)
    assert "a\\x1b[2J\\x1b[Hforged: line\\u202e.png" in out and "b\\n\\x1b[2J" in out


def test_the_skipped_files_of_a_pair_report_are_escaped(tmp_path: Path) -> None:
    for side in ("clean", "captured"):
        write_image(torch.zeros(3, 20, 20, dtype=torch.uint8), tmp_path / side / "ok.png")
    write_image(torch.zeros(3, 20, 20, dtype=torch.uint8), tmp_path / "clean" / f"x\n{FORGED}.png")
    summary = discover_pairs(tmp_path).summary()
    _assert_safe(summary)
    assert printable(f"x\n{FORGED}.png") in summary


def test_printable_keeps_text_of_every_script_and_escapes_only_what_moves_the_cursor() -> None:
    assert printable("Café 東京 ü-ß") == "Café 東京 ü-ß"
    assert printable("a\tb\rc\x00d\x7fe\u2028f\u200bg") == "a\\tb\\rc\\x00d\\x7fe\\u2028f\\u200bg"
