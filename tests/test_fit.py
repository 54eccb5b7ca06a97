"""fit_profile and `camdegrade fit`: pairs folder → profile, end to end (also under torchrun with 2 processes)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
import torch
import torch.nn.functional as F

from camdegrade import CameraDegrade, CameraProfile, DomainShiftNet, LocalAffineNet, ProfileError, load_profile
from camdegrade._support.seeds import derived_generator
from camdegrade.cli import main
from camdegrade.fitting.fit import fit_profile
from camdegrade.fitting.network.training import fit_network, random_crop_batch
from camdegrade.fitting.recipe import FitConfig
from camdegrade.io import write_image
from profiles_for_tests import seeded_network

QUICK = ["--epochs", "2", "--crop", "16", "--batch-size", "4", "--crops-per-pair", "2", "--quiet"]


def make_pairs_folder(root, count: int = 6, size: int = 32):
    """clean/ and captured/ with a learnable degradation: darker, softer and noisy."""
    generator = torch.Generator().manual_seed(0)
    for index in range(count):
        clean = torch.rand(1, 3, size, size, generator=generator)
        captured = F.avg_pool2d(clean * 0.8 + 0.05, 3, stride=1, padding=1, count_include_pad=False)
        captured = captured + 0.02 * torch.randn(captured.shape, generator=generator)
        write_image(clean[0], root / "clean" / f"img{index}.png")
        write_image(captured[0].clamp(0, 1), root / "captured" / f"img{index}.png")
    return root


def test_fit_profile_records_how_it_was_made(tmp_path):
    folder = make_pairs_folder(tmp_path / "pairs")
    lines: list[str] = []
    recipe = FitConfig.recipe("fast").replace(epochs=2, crop=16, batch_size=4, crops_per_pair=2, val_fraction=0.34)
    profile = fit_profile(folder, recipe, name="tiny", log=lines.append)
    assert profile.name == "tiny" and profile.network is not None
    assert profile.fitted["pairs"] == 6 and profile.fitted["validation_pairs"] == 2
    assert profile.fitted["recipe"]["epochs"] == 2 and profile.fitted["recipe"]["crop"] == 16
    # 32² random images have no flat pixel to measure noise on: the stage is tried, and the reason it is not kept
    assert "noise" not in profile.effect_names and "too few flat pixels" in profile.fitted["effects"]["noise"]["reason"]
    assert profile.quality["validation_pairs"] == 2 and "network_psnr_db" in profile.quality
    assert (
        profile.quality["network_psnr_db"] >= profile.quality["baseline_psnr_db"] > profile.quality["identity_psnr_db"]
    )
    assert any("6 pair" in line for line in lines)
    fidelity = profile.quality["fidelity"]
    assert fidelity["frames"] == 2 and fidelity["pixels"] == 2 * 32 * 32 and len(fidelity["bands"]) == 5
    assert fidelity["grid_ratio"] > 0 and fidelity["noise_ratio"] is None  # 32² random images: nothing flat
    json.dumps(profile.quality, allow_nan=False)
    assert load_profile(profile.save(tmp_path / "tiny.safetensors")).quality["fidelity"] == fidelity


def test_camdegrade_info_shows_the_fidelity_of_a_new_fit(tmp_path, capsys):
    folder = make_pairs_folder(tmp_path / "pairs")
    recipe = FitConfig.recipe("fast").replace(epochs=1, crop=16, batch_size=4, crops_per_pair=1, val_fraction=0.34)
    path = fit_profile(folder, recipe, name="tiny").save(tmp_path / "tiny.safetensors")
    capsys.readouterr()
    assert main(["info", str(path)]) == 0
    assert "           fidelity: grid " in capsys.readouterr().out


@pytest.mark.slow
def test_fit_profile_threads_apply_during_the_fit_and_are_restored(tmp_path):
    before = torch.get_num_threads()
    seen: list[int] = []
    fit_profile(
        make_pairs_folder(tmp_path / "pairs"),
        FitConfig(epochs=1, crop=16, batch_size=4, crops_per_pair=1),
        threads=before + 1,
        callback=lambda result: seen.append(torch.get_num_threads()),
    )
    assert seen == [before + 1]
    assert torch.get_num_threads() == before
    with pytest.raises(ValueError, match=r"threads must be an integer from 1 to \d+ or None, got threads=0"):
        fit_profile(make_pairs_folder(tmp_path / "other"), threads=0)


@pytest.mark.slow
def test_fit_profile_same_seed_same_bytes(tmp_path):
    folder = make_pairs_folder(tmp_path / "pairs")
    recipe = FitConfig(epochs=2, crop=16, batch_size=4, crops_per_pair=2, seed=3)
    first = fit_profile(folder, recipe)
    second = fit_profile(folder, recipe)
    first.fitted.pop("fit_minutes"), second.fitted.pop("fit_minutes")
    assert first.save(tmp_path / "a.safetensors").read_bytes() == second.save(tmp_path / "b.safetensors").read_bytes()


def test_fit_profile_rejects_unknown_effects(tmp_path):
    with pytest.raises(ValueError, match=r"effects must be effect names from .*unknown \['lens_flare'\]"):
        fit_profile(make_pairs_folder(tmp_path / "pairs"), FitConfig().replace(effects=["lens_flare"]))


def test_cli_fit_writes_a_loadable_profile_and_removes_its_checkpoint(tmp_path, capsys):
    folder = make_pairs_folder(tmp_path / "pairs")
    out = tmp_path / "cam.safetensors"
    assert main(["fit", str(folder), "-o", str(out), *QUICK]) == 0
    assert "wrote" in capsys.readouterr().out
    profile = load_profile(out)
    assert profile.name == "cam"
    image = torch.randint(0, 256, (3, 20, 20), dtype=torch.uint8)
    assert CameraDegrade(out, seed=0)(image).shape == (3, 20, 20)
    assert not (tmp_path / "cam.ckpt.safetensors").exists()


@pytest.mark.slow
def test_cli_fit_interrupted_keeps_the_good_profile_and_resumes(tmp_path, monkeypatch, capsys):
    folder = make_pairs_folder(tmp_path / "pairs")
    out = tmp_path / "cam.safetensors"
    assert main(["fit", str(folder), "-o", str(out), *QUICK]) == 0
    good = out.read_bytes()

    import camdegrade.fitting.network.training as training

    real_epoch = training._train_one_epoch
    calls = {"n": 0}

    def flaky_epoch(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt
        return real_epoch(*args, **kwargs)

    monkeypatch.setattr(training, "_train_one_epoch", flaky_epoch)
    assert main(["fit", str(folder), "-o", str(out), *QUICK, "--seed", "1"]) == 130
    assert "--resume" in capsys.readouterr().err
    assert out.read_bytes() == good  # the earlier profile is never replaced by a partial fit
    assert (tmp_path / "cam.ckpt.safetensors").exists()
    monkeypatch.setattr(training, "_train_one_epoch", real_epoch)
    assert main(["fit", str(folder), "-o", str(out), *QUICK, "--seed", "1", "--resume"]) == 0
    assert out.read_bytes() != good and load_profile(out).fitted["recipe"]["seed"] == 1


def test_cli_fit_reports_missing_pairs(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert main(["fit", str(tmp_path / "empty"), "-o", str(tmp_path / "x.safetensors"), *QUICK]) == 1
    assert "error" in capsys.readouterr().err


@pytest.mark.slow
def test_torchrun_two_processes_fit(tmp_path):
    folder = make_pairs_folder(tmp_path / "pairs")
    out = tmp_path / "ddp.safetensors"
    command = [
        sys.executable,
        "-m",
        "torch.distributed.run",
        "--nproc_per_node",
        "2",
        "--master_port",
        "29517",
        "-m",
        "camdegrade",
        "fit",
        str(folder),
        "-o",
        str(out),
        *QUICK,
        "--threads",
        "1",
    ]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    result = subprocess.run(command, capture_output=True, text=True, timeout=240, env=env, check=False)
    assert result.returncode == 0, result.stderr[-2000:]
    profile = load_profile(out)
    single = fit_profile(folder, FitConfig(epochs=2, crop=16, batch_size=4, crops_per_pair=2))
    assert profile.quality["network_psnr_db"] == pytest.approx(single.quality["network_psnr_db"], abs=0.05)


def test_simulate_then_fit_end_to_end(tmp_path, capsys):
    generator = torch.Generator().manual_seed(1)
    for index in range(5):
        smooth = F.interpolate(torch.rand(1, 3, 8, 8, generator=generator), size=(48, 48), mode="bilinear")
        write_image(smooth[0], tmp_path / "photos" / f"p{index}.png")
    assert main(["simulate", "lowcost-robot", str(tmp_path / "photos"), str(tmp_path / "pairs"), "--seed", "2"]) == 0
    assert "wrote 5 pair(s)" in capsys.readouterr().out
    out = tmp_path / "robot.safetensors"
    assert main(["fit", str(tmp_path / "pairs"), "-o", str(out), *QUICK, "--val-fraction", "0.4"]) == 0
    degraded = CameraDegrade(out, seed=0)(torch.randint(0, 256, (2, 3, 40, 40), dtype=torch.uint8))
    assert degraded.shape == (2, 3, 40, 40) and degraded.dtype == torch.uint8
    assert load_profile(out).fitted["pairs"] == 5


def test_cli_fit_align_prints_the_shifts(tmp_path, capsys):
    folder = make_pairs_folder(tmp_path / "pairs", count=4)
    assert main(["fit", str(folder), "-o", str(tmp_path / "a.safetensors"), *QUICK, "--align"]) == 0
    out = capsys.readouterr().out
    assert "largest shift" in out and "img0" in out


# --- starting from a profile's network (--init-from) --------------------------------------------------------------


def _tiny_pairs(count: int = 4, size: int = 32) -> list[tuple[torch.Tensor, torch.Tensor]]:
    generator = torch.Generator().manual_seed(5)
    cleans = [torch.rand(3, size, size, generator=generator) for _ in range(count)]
    return [(clean, (clean * 0.8 + 0.05).clamp(0, 1)) for clean in cleans]


def test_fit_network_starts_from_the_initial_weights():
    pairs = _tiny_pairs()
    initial = seeded_network(7)
    before = {key: value.clone() for key, value in initial.state_dict().items()}
    config = FitConfig(epochs=1, crop=16, batch_size=8, crops_per_pair=2, lr=1e-12, precision="float32", arch="paper")
    network, history = fit_network(pairs, [], config, initial=initial)  # one step
    assert network is not initial
    for key, value in network.state_dict().items():
        assert torch.equal(initial.state_dict()[key], before[key])  # the initial network is not changed
        assert torch.allclose(value, before[key], rtol=0, atol=1e-9), key
    # the epoch's one batch was scored by the initial network: the same crops the fit draws from its seed's stream
    clean, captured = random_crop_batch(pairs, 16, 8, derived_generator(0, "training-crops"))
    with torch.no_grad():
        expected = F.mse_loss(initial(clean), captured).item()
    assert history[0].train_loss == pytest.approx(expected, rel=1e-5)
    fresh, _ = fit_network(pairs, [], config)
    assert not torch.allclose(fresh.decode2.weight, before["decode2.weight"])


def test_fit_network_refuses_an_initial_network_it_cannot_start_from():
    config = FitConfig(epochs=1, crop=16, batch_size=4, crops_per_pair=1, arch="paper")
    expected = r"initial must be a network of arch 'paper', width 64 and curves False .*width=8"
    with pytest.raises(ValueError, match=expected):
        fit_network(_tiny_pairs(), [], config, initial=DomainShiftNet(width=8))
    with pytest.raises(ValueError, match=r"initial must be a network of arch 'paper', .*got arch='local_affine'"):
        fit_network(_tiny_pairs(), [], config, initial=LocalAffineNet())
    with pytest.raises(TypeError, match="initial must be a DomainShiftNet, a LocalAffineNet or None, got dict"):
        fit_network(_tiny_pairs(), [], config, initial={})  # type: ignore[arg-type]


@pytest.mark.slow
def test_fit_profile_init_from_a_file_keeps_its_weights_at_a_tiny_lr_and_records_it(tmp_path):
    start = CameraProfile(seeded_network(3), name="start").save(tmp_path / "start.safetensors")
    folder = make_pairs_folder(tmp_path / "pairs", count=4)
    recipe = FitConfig(epochs=1, crop=16, batch_size=4, crops_per_pair=1, lr=1e-12, val_fraction=0.0).replace(
        effects=()
    )
    profile = fit_profile(folder, recipe, init_from=start)
    assert profile.network is not None
    for key, value in profile.network.state_dict().items():
        assert torch.allclose(value, seeded_network(3).state_dict()[key], rtol=0, atol=1e-9), key
    assert profile.fitted["init_from"] == str(start)
    assert fit_profile(folder, recipe).fitted["init_from"] is None
    assert fit_profile(folder, recipe, init_from=load_profile(start)).fitted["init_from"] == "start"


def test_fit_profile_records_the_torch_and_torchvision_versions(tmp_path):
    import torchvision

    profile = fit_profile(
        make_pairs_folder(tmp_path / "pairs", count=4), FitConfig(epochs=1, crop=16, crops_per_pair=1)
    )
    assert torch.__version__.startswith(profile.fitted["torch"])
    assert torchvision.__version__.startswith(profile.fitted["torchvision"])


@pytest.mark.parametrize(
    ("init_from", "error", "message"),
    [
        (CameraProfile(None, name="effects-only"), ValueError, "init_from: profile 'effects-only' has no network"),
        (CameraProfile(DomainShiftNet(width=8), name="narrow"), ValueError, "'narrow' has a network of width 8"),
        (3, TypeError, "init_from must be a CameraProfile, a profile name, a path or None, got int"),
        ("no-such-camera", ProfileError, "neither an existing file nor a built-in profile"),
    ],
)
def test_fit_profile_refuses_what_it_cannot_start_from_before_reading_pairs(tmp_path, init_from, error, message):
    with pytest.raises(error, match=message):
        fit_profile(tmp_path / "no-pairs-here", init_from=init_from)


def test_cli_fit_init_from(tmp_path, capsys):
    folder = make_pairs_folder(tmp_path / "pairs", count=4)
    out = tmp_path / "refit.safetensors"
    assert main(["fit", str(folder), "-o", str(out), *QUICK, "--init-from", "city100-iphonex", "--lr", "0.001"]) == 0
    assert load_profile(out).fitted["init_from"] == "city100-iphonex"
    capsys.readouterr()
    assert main(["fit", str(folder), "-o", str(tmp_path / "x.safetensors"), *QUICK, "--init-from", "nope"]) == 1
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "profile 'nope' is neither" in err
    assert not (tmp_path / "x.safetensors").exists()
