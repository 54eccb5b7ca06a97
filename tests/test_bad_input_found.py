"""Bad inputs found beyond issue 17's list, trying camdegrade as an attacker and as a careless user. Each of these
failed before its fix (a traceback, a wrong message, a deleted or overwritten file, or seconds and a gigabyte)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from safetensors.torch import save_file

import camdegrade.diagnose.core as core
import camdegrade.fitting.steps.network as network_step
import camdegrade.io
from bad_inputs import good_image, one_line_error, profile_file, run_cli
from camdegrade import CameraProfile, load_profile
from camdegrade.effects import Vignetting
from camdegrade.errors import PairsError, ProfileError
from camdegrade.io import read_image, write_image
from camdegrade.pairs.discovery import discover_pairs
from camdegrade.profile import METADATA_KEY, serialize_metadata
from test_fit import QUICK, make_pairs_folder


def test_a_manifest_field_past_the_csv_limit_is_named(tmp_path: Path) -> None:
    folder = make_pairs_folder(tmp_path / "pairs", count=2)
    manifest = folder / "pairs.csv"
    manifest.write_bytes(b'clean,captured\nclean/img0.png,captured/img0.png\n"' + b"x" * 200_000 + b'",b.png\n')
    with pytest.raises(PairsError, match=r"manifest '.*pairs\.csv' line 3 is not valid CSV \(field larger"):
        discover_pairs(manifest)


def test_a_long_file_name_is_written_atomically_too(tmp_path: Path) -> None:
    """244 bytes is a valid name; with the temporary's ``.NAME.<32 hex>.tmp`` around it, it was not."""
    target = tmp_path / ("o" * 240 + ".png")
    write_image(torch.full((3, 4, 4), 7, dtype=torch.uint8), target)
    assert read_image(target).unique().tolist() == [7]
    assert [path.name for path in tmp_path.iterdir()] == [target.name]


def test_fit_refuses_a_checkpoint_that_is_the_output(tmp_path: Path, monkeypatch, capsys) -> None:
    """The checkpoint is deleted after a successful fit: it used to take the fitted profile with it."""
    monkeypatch.setattr(network_step, "fit_network", lambda *a, **k: pytest.fail("trained before checking"))
    out = tmp_path / "cam.safetensors"
    argv = ["fit", make_pairs_folder(tmp_path / "pairs"), "-o", out, "--checkpoint", out, *QUICK]
    code, _, err = run_cli(argv, capsys)
    assert code == 1 and "--checkpoint must differ from --output" in one_line_error(err)


def test_diagnose_never_writes_over_the_profile_it_reads(tmp_path: Path, monkeypatch, capsys) -> None:
    monkeypatch.setattr(core, "attribute", lambda *a, **k: pytest.fail("diagnosed before checking"))
    profile = CameraProfile(None, [], name="identity").save(tmp_path / "p.safetensors")
    before = profile.read_bytes()
    argv = ["diagnose", profile, make_pairs_folder(tmp_path / "pairs", count=8), "--out-profile", profile]
    code, _, err = run_cli(argv, capsys)
    assert code == 1 and "is the input file itself" in one_line_error(err)
    assert profile.read_bytes() == before


def test_a_profile_declaring_thousands_of_stages_is_refused_at_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """800 KB of metadata used to build 20000 effects (3 s, about 1 GB) before finding their tensors missing: now
    refused before a single stage is built."""
    specs = [{"name": "vignetting", "config": {}}] * 20_000
    path = profile_file(tmp_path / "many.safetensors", CameraProfile(None, []), {"effects": specs})
    built = []
    original = Vignetting.__init__

    def counting_init(self: Vignetting, *args: object, **kwargs: object) -> None:
        built.append(1)
        original(self, *args, **kwargs)

    monkeypatch.setattr(Vignetting, "__init__", counting_init)
    with pytest.raises(ProfileError, match=r"declares 20000 effect stages, more than camdegrade builds \(64\)"):
        load_profile(path)
    assert built == []


def test_a_long_list_of_mismatched_tensors_is_shortened(tmp_path: Path) -> None:
    declared = CameraProfile(None, [Vignetting() for _ in range(30)])  # 60 tensors, none in the file
    path = tmp_path / "p.safetensors"
    save_file({"unrelated": torch.zeros(1)}, str(path), metadata=serialize_metadata(declared.metadata()))
    with pytest.raises(ProfileError, match=r"missing tensors: effects\.0\.k1, .* and 50 more; unexpected") as info:
        load_profile(path)
    assert len(str(info.value)) < 1000


def test_deeply_nested_metadata_is_a_profile_error(tmp_path: Path) -> None:
    nested = "[" * 100_000 + "]" * 100_000
    text = '{"format": "camdegrade-profile", "format_version": 1, "fitted": ' + nested + "}"
    save_file({}, str(tmp_path / "deep.safetensors"), metadata={METADATA_KEY: text})
    with pytest.raises(ProfileError, match="nested too deeply"):
        load_profile(tmp_path / "deep.safetensors")


def test_ctrl_c_during_a_batch_is_one_line(tmp_path: Path, monkeypatch, capsys) -> None:
    def interrupted(path):
        raise KeyboardInterrupt

    profile = CameraProfile(None, []).save(tmp_path / "p.safetensors")
    good_image(tmp_path / "in" / "a.png")
    monkeypatch.setattr(camdegrade.io, "read_image", interrupted)
    code, _, err = run_cli(["apply", profile, tmp_path / "in", tmp_path / "out"], capsys)
    assert code == 130 and one_line_error(err) == "camdegrade: interrupted"
