"""Fitting and diagnosis under bad input (issue 17): unreadable pairs are skipped and reported, a resume never
starts fresh or continues someone else's fit silently, broken checkpoints and manifests are named, seeds too large
for torch are refused, and a diagnosis refuses to conclude from too few pairs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from safetensors import safe_open
from safetensors.torch import save_file

from bad_inputs import cut_image, one_line_error, png_with_rows, run_cli
from camdegrade import CameraProfile, load_profile
from camdegrade.diagnose import diagnose
from camdegrade.errors import CamdegradeError, PairsError
from camdegrade.fitting.fit import fit_profile
from camdegrade.fitting.network.checkpoint import CHECKPOINT_KEY, load_checkpoint
from camdegrade.fitting.network.training import fit_network
from camdegrade.fitting.recipe import FitConfig
from camdegrade.io import write_image
from camdegrade.pairs.discovery import discover_pairs
from camdegrade.sim import simulate_pairs
from test_fit import QUICK as CLI_QUICK
from test_fit import make_pairs_folder
from test_training import TINY, synthetic_pairs

BIG_SEED = 2**70
QUICK = FitConfig(epochs=1, crop=16, batch_size=4, crops_per_pair=1)


def test_fit_skips_a_png_whose_data_is_short(tmp_path: Path) -> None:
    folder = make_pairs_folder(tmp_path / "pairs")
    png_with_rows(folder / "captured" / "img2.png", 32, 32, rows=4)  # valid header, 28 rows missing
    lines: list[str] = []
    profile = fit_profile(folder, QUICK, log=lines.append)
    assert profile.fitted["pairs"] == 5 and profile.fitted["skipped"] == 1
    assert any("img2.png" in line and "truncated" in line for line in lines)
    assert [Path(entry["path"]).name for entry in profile.fitted["unreadable"]] == ["img2.png"]


def test_cli_fit_writes_the_profile_then_reports_unreadable_files(tmp_path: Path, capsys) -> None:
    folder = make_pairs_folder(tmp_path / "pairs")
    cut_image(folder / "captured" / "img4.png", keep=0.5, size=(32, 32))
    out = tmp_path / "cam.safetensors"
    code, stdout, err = run_cli(["fit", folder, "-o", out, *CLI_QUICK], capsys)
    assert code == 1 and "1 file(s) could not be read" in one_line_error(err)
    assert load_profile(out).fitted["pairs"] == 5
    assert "img4.png" in stdout[stdout.rindex("could not be read") :]


def test_resume_without_a_checkpoint_is_an_error(tmp_path: Path) -> None:
    pairs = synthetic_pairs()
    missing = tmp_path / "typo.ckpt.safetensors"
    with pytest.raises(CamdegradeError, match=r"resume.*'.*typo\.ckpt\.safetensors' does not exist"):
        fit_network(pairs[:3], pairs[3:], TINY, checkpoint=missing, resume=True)


def test_resume_refuses_a_checkpoint_of_other_pairs(tmp_path: Path) -> None:
    checkpoint = tmp_path / "fit.ckpt.safetensors"
    fit_network(synthetic_pairs(seed=0)[:3], [], TINY, checkpoint=checkpoint)
    with pytest.raises(CamdegradeError, match=r"other training pairs"):
        fit_network(synthetic_pairs(seed=1)[:3], [], TINY, checkpoint=checkpoint, resume=True)
    with pytest.raises(CamdegradeError, match=r"other training pairs"):  # same images, one more pair
        fit_network(synthetic_pairs(seed=0), [], TINY, checkpoint=checkpoint, resume=True)
    fit_network(synthetic_pairs(seed=0)[:3], [], TINY, checkpoint=checkpoint, resume=True)  # the same pairs resume


def _rewrite_checkpoint(path: Path, drop: str) -> None:
    with safe_open(str(path), framework="pt") as handle:
        metadata = json.loads(handle.metadata()[CHECKPOINT_KEY])
        tensors = {key: handle.get_tensor(key) for key in handle.keys()}  # noqa: SIM118
    metadata.pop(drop, None)
    tensors.pop(drop, None)
    save_file(tensors, str(path), metadata={CHECKPOINT_KEY: json.dumps(metadata)})


@pytest.mark.parametrize("key", ["scheduler", "param_groups", "epoch", "generator"])
def test_a_checkpoint_missing_a_key_names_it(tmp_path: Path, key: str) -> None:
    checkpoint = tmp_path / "fit.ckpt.safetensors"
    pairs = synthetic_pairs()
    fit_network(pairs[:3], [], TINY, checkpoint=checkpoint)
    _rewrite_checkpoint(checkpoint, key)
    with pytest.raises(CamdegradeError, match=rf"checkpoint '.*fit\.ckpt\.safetensors' lacks '{key}'") as info:
        load_checkpoint(checkpoint)
    assert "\n" not in str(info.value)


def test_a_checkpoint_with_broken_metadata_json_is_named(tmp_path: Path) -> None:
    checkpoint = tmp_path / "fit.ckpt.safetensors"
    save_file({"generator": torch.zeros(1, dtype=torch.uint8)}, str(checkpoint), metadata={CHECKPOINT_KEY: "{oops"})
    with pytest.raises(CamdegradeError, match=r"fit\.ckpt\.safetensors.*metadata is not valid JSON"):
        load_checkpoint(checkpoint)


def test_a_manifest_line_that_is_not_utf8_is_named(tmp_path: Path) -> None:
    folder = make_pairs_folder(tmp_path / "pairs", count=2)
    manifest = folder / "pairs.csv"
    manifest.write_bytes(b"clean,captured\nclean/img0.png,captured/img0.png\nclean/img1.png,caf\xe9/img1.png\n")
    with pytest.raises(PairsError, match=r"manifest '.*pairs\.csv' line 3 is not UTF-8"):
        discover_pairs(manifest)


def test_a_fifo_is_not_a_pairs_source(tmp_path: Path) -> None:
    import os

    fifo = tmp_path / "pairs.csv"
    os.mkfifo(fifo)
    with pytest.raises(PairsError, match=r"is not a regular file or folder"):
        discover_pairs(fifo)


def _write_pairs(folder: Path, count: int, mismatched: int = 0) -> Path:
    generator = torch.Generator().manual_seed(0)
    for index in range(count):
        clean = torch.rand(3, 32, 32, generator=generator)
        write_image(clean, folder / "clean" / f"s{index:02d}.png")
        size = 24 if index < mismatched else 32
        write_image((clean[:, :size, :size] * 0.8).clamp(0, 1), folder / "captured" / f"s{index:02d}.png")
    return folder


def test_diagnose_refuses_too_few_pairs(tmp_path: Path) -> None:
    with pytest.raises(PairsError, match=r"at least 4 calibration and 4 held-out pairs.*got 1 and 1"):
        diagnose(CameraProfile(None, []), _write_pairs(tmp_path / "pairs", 2))


@pytest.mark.slow
def test_diagnose_reports_the_pairs_it_skipped_in_stdout_and_json(tmp_path: Path, capsys) -> None:
    folder = _write_pairs(tmp_path / "pairs", 11, mismatched=2)
    cut_image(folder / "captured" / "s10.png", keep=0.5, size=(32, 32))  # unreadable: the run ends with status 1
    CameraProfile(None, [], name="identity").save(tmp_path / "p.safetensors")
    argv = ["diagnose", tmp_path / "p.safetensors", folder, "--json", tmp_path / "r.json", "--candidates", "tone"]
    code, out, err = run_cli(argv, capsys)
    assert code == 1 and "1 file(s) could not be read" in one_line_error(err)
    assert "3 skipped" in out and "s00.png" in out and "size mismatch" in out
    data = json.loads((tmp_path / "r.json").read_text())
    assert [Path(entry["path"]).name for entry in data["skipped"]] == ["s00.png", "s01.png", "s10.png"]
    assert [entry["reason"].split(":")[0] for entry in data["skipped"]] == ["size mismatch"] * 2 + ["unreadable"]
    assert data["calibration_pairs"] + data["held_out_pairs"] == 8


@pytest.mark.parametrize(
    "call",
    [
        lambda tmp: fit_profile(make_pairs_folder(tmp / "pairs"), QUICK.replace(seed=BIG_SEED)),
        lambda tmp: diagnose(CameraProfile(None, []), _write_pairs(tmp / "pairs", 8), seed=BIG_SEED),
        lambda tmp: simulate_pairs("lowcost-robot", make_pairs_folder(tmp / "pairs") / "clean", tmp / "out", BIG_SEED),
    ],
)
def test_a_seed_too_large_for_torch_is_named(tmp_path: Path, call) -> None:
    with pytest.raises(ValueError, match=rf"seed must be an integer from -2\*\*63 to 2\*\*64 - 1, got seed={BIG_SEED}"):
        call(tmp_path)
