"""The fast CLI (issue 19): ``--help``, ``--version``, ``list`` and ``info`` without torch; ``import camdegrade``
imports names on first use; ``info`` shows what the profile says, and warns when torch is another major release."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch

import camdegrade
import camdegrade._profile_format.header as metadata_module
from bad_inputs import one_line_error, profile_file, run_cli
from camdegrade import ProfileError, load_profile
from camdegrade._profile_format.check import effect_facts
from camdegrade._profile_format.header import read_header, running_versions
from camdegrade._profile_format.network_entry import DEFAULT_NETWORK_WIDTH, MAX_NETWORK_WIDTH, check_network_config
from camdegrade._profile_format.summary import profile_summary
from camdegrade.effects import EFFECTS
from camdegrade.network import MAX_WIDTH, DomainShiftNet
from profiles_for_tests import deterministic_profile, stochastic_profile

HEAVY = ("torch", "torchvision")


def _python(code: str, *options: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, *options, "-c", code], capture_output=True, text=True, check=False)


def test_help_version_list_and_info_import_no_torch() -> None:
    code = f"""
import contextlib, io, json, sys
from camdegrade.cli import main
results = {{}}
runs = (["--help"], ["--version"], ["list"], ["info", "city100-iphonex"], ["info", "lowcost-robot-sim"],
        ["info", "city100-iphonex", "--json"])
for argv in runs:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        try:
            status = main(argv)
        except SystemExit as stop:
            status = stop.code
    results[" ".join(argv)] = [status, out.getvalue()]
print(json.dumps({{"results": results, "heavy": [name for name in {HEAVY!r} if name in sys.modules]}}))
"""
    run = _python(code)
    assert run.returncode == 0, run.stderr
    report = json.loads(run.stdout)
    assert report["heavy"] == []
    results = report["results"]
    assert all(status == 0 for status, _ in results.values()), results
    assert "usage:" in results["--help"][1] and "camdegrade 0" in results["--version"][1]
    assert "city100-iphonex" in results["list"][1] and "lowcost-robot-sim" in results["list"][1]
    for name in ("city100-iphonex", "lowcost-robot-sim"):
        chain = load_profile(name).effects
        info = results[f"info {name}"][1]
        for index, effect in enumerate(chain):
            assert f"  {index}. {effect.name} [{effect.stage}] " in info, (name, info)
    jitter, blur = load_profile("city100-iphonex").effects[:2]
    assert f"sigma_x={float(blur.sigma_x):.3g}" in results["info city100-iphonex"][1]
    assert f"sigma={float(jitter.sigma):.3g}" in results["info city100-iphonex"][1]
    assert json.loads(results["info city100-iphonex --json"][1])["name"] == "city100-iphonex"


def test_the_entry_point_module_imports_no_torch_for_info() -> None:
    run = subprocess.run(
        [sys.executable, "-X", "importtime", "-m", "camdegrade", "info", "city100-iphonex"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert run.returncode == 0, run.stderr
    imported = {line.split("|")[-1].strip() for line in run.stderr.splitlines() if line.startswith("import time:")}
    assert "camdegrade._profile_format.header" in imported  # the measurement works
    assert not imported & set(HEAVY)


@pytest.mark.slow
def test_import_camdegrade_imports_torch_only_when_a_name_needs_it() -> None:
    code = f"""
import sys
heavy = lambda: [name for name in {HEAVY!r} if name in sys.modules]
import camdegrade
print(heavy())
camdegrade.ProfileError, camdegrade.__version__, camdegrade.list_profiles()
print(heavy())
from camdegrade import CameraDegrade
print(heavy())
"""
    run = _python(code)
    assert run.returncode == 0, run.stderr
    assert run.stdout.split("\n")[:3] == ["[]", "[]", "['torch', 'torchvision']"]


def test_every_public_name_is_the_object_its_module_defines() -> None:
    from camdegrade import data, fitting, network, profile, sim, transform
    from camdegrade.fitting import unpaired

    homes = {
        "BatchDegrade": data,
        "DegradedDataset": data,
        "DegradedIterableDataset": data,
        "IndexedDataset": data,
        "FitConfig": fitting,
        "PairSet": fitting,
        "distill_profile": fitting,
        "fit_unpaired": unpaired,
        "fit_profile": fitting,
        "DomainShiftNet": network,
        "CameraProfile": profile,
        "load_profile": profile,
        "list_profiles": profile,
        "VirtualCamera": sim,
        "simulate_pairs": sim,
        "CameraDegrade": transform,
    }
    for name in camdegrade.__all__:
        value = getattr(camdegrade, name)
        if name in homes:
            assert value is getattr(homes[name], name), name
    assert set(camdegrade.__all__) <= set(dir(camdegrade))
    namespace: dict[str, object] = {}
    exec("from camdegrade import *", namespace)
    assert set(camdegrade.__all__) <= set(namespace)
    assert camdegrade.engine.__name__ == "camdegrade.engine"  # a module, imported on first access
    with pytest.raises(AttributeError, match="has no attribute 'no_such_name'"):
        camdegrade.no_such_name  # noqa: B018


@pytest.mark.slow
@pytest.mark.parametrize("first", ["the subpackage", "the top-level name"])
def test_camdegrade_diagnose_is_the_function_and_the_subpackage_whichever_comes_first(first: str) -> None:
    """Importing a subpackage sets it on its parent, so ``camdegrade.diagnose`` is the subpackage: it must be callable
    as the function too, in a fresh interpreter whichever import comes first."""
    imports = ["import camdegrade.diagnose.report", "from camdegrade import diagnose"]
    code = "\n".join(
        [
            *(imports if first == "the subpackage" else imports[::-1]),
            """
import inspect, sys
import camdegrade, camdegrade.diagnose as package
from camdegrade.diagnose import DiagnosisReport, diagnose as function
from camdegrade.diagnose.core import diagnose as core
assert diagnose is camdegrade.diagnose is package and function is core
assert camdegrade.diagnose.DiagnosisReport is DiagnosisReport and camdegrade.diagnose.report.DiagnosisReport
assert inspect.signature(diagnose) == inspect.signature(core)
try:
    diagnose("city100-iphonex", [])
except Exception as error:  # the function ran: it refuses no pairs
    print(error)
""",
        ]
    )
    run = _python(code)
    assert run.returncode == 0, run.stderr
    assert "pairs must hold at least one (clean, captured) pair" in run.stdout


@pytest.mark.parametrize("name", ["city100-iphonex", "city100-iphonex-fast", "lowcost-robot-sim", "stochastic"])
def test_info_summarizes_in_25_lines_of_120_characters(name: str, tmp_path: Path, capsys) -> None:
    if name == "stochastic":
        name = str(stochastic_profile().save(tmp_path / "cam.safetensors"))
    status, out, err = run_cli(["info", name], capsys)
    assert status == 0 and err == ""
    lines = out.splitlines()
    assert len(lines) <= 25 and max(len(line) for line in lines) <= 120, out
    profile = load_profile(name)
    assert lines[0] == f"profile    {profile.name}"
    chain = next(index for index, line in enumerate(lines) if line.startswith("chain      "))
    for index, effect in enumerate(profile.effects):  # one line per stage, in order
        assert lines[chain + 1 + index].startswith(f"  {index}. {effect.name} [{effect.stage}] "), out
    assert any(line.startswith("versions   fitted with torch ") for line in lines)
    assert "--json" in lines[-1]


def test_info_of_the_built_in_says_what_a_person_needs() -> None:
    """The chain with its key values, the network, the held-out PSNR, fidelity, critics and the warnings."""
    out = profile_summary("city100-iphonex")
    profile, quality = load_profile("city100-iphonex"), read_header("city100-iphonex").metadata["quality"]
    parameters = sum(parameter.numel() for parameter in profile.network.parameters())
    assert f"network    LocalAffineNet (curves, upsample bilinear, width 64): {parameters:,} parameters" in out
    assert "  0. jitter [optics] scale=8, sigma=0.609" in out and "  1. blur [optics] sigma_x=0.6, sigma_y=0.6" in out
    assert "  2. sharpen [isp] amount=1.5, sigma=1" in out
    # a stage that draws: the deterministic output's PSNR (31.09) and a sample's (27.94) both
    held_out = (
        f"held-out   16 pairs: PSNR identity {quality['identity_psnr_db']:.2f} dB -> profile 31.09 dB mean, 27.94 dB"
    )
    assert held_out + " sampled" in out
    bands = " ".join(f"{value:+.2f}" for value in quality["fidelity"]["bands"])
    assert f"bands log2 {bands}, flat noise 0.97" in out and "fidelity: grid 0.82" in out
    assert "critic: paired 0.82 ± " in out and "image-only 0.59 ± " in out and "(8 critic(s)" in out
    assert "steps      kept: denoise, jitter, network, response, texture; dropped: noise, vignetting" in out
    assert "warnings   none" in out


def test_a_fits_warnings_and_long_text_stay_within_the_width(tmp_path: Path) -> None:
    profile = stochastic_profile()
    profile.description = "a long description " * 20
    profile.fitted = {"warnings": ["the network is worse than the identity " * 5, "second"]}
    lines = profile_summary(profile.save(tmp_path / "cam.safetensors")).splitlines()
    assert max(len(line) for line in lines) <= 120
    assert lines[2].endswith(" ...") and len([line for line in lines if "a long description" in line]) == 2
    warned = [index for index, line in enumerate(lines) if line.startswith("warnings   the network is worse")]
    assert warned and "second" in "".join(lines[warned[0] : warned[0] + 3])


@pytest.mark.parametrize("name", ["city100-iphonex", "lowcost-robot-sim", "stochastic"])
def test_info_json_is_the_full_record(name: str, tmp_path: Path, capsys) -> None:
    if name == "stochastic":
        name = str(stochastic_profile().save(tmp_path / "cam.safetensors"))
    status, out, err = run_cli(["info", name, "--json"], capsys)
    assert status == 0 and err == ""
    record = json.loads(out)
    values, versions = record.pop("values"), record.pop("versions")
    assert record == read_header(name).metadata  # every metadata key, as stored
    profile = load_profile(name)
    assert (record["fitted"], record["quality"]) == (profile.fitted, profile.quality)
    expected = {f"effects.{key}": value for key, value in profile.effects.state_dict().items()}
    assert sorted(values) == sorted(expected)
    for key, tensor in expected.items():
        assert torch.allclose(torch.tensor(values[key], dtype=torch.float64), tensor.double(), atol=1e-6), key
    assert versions["running"] == running_versions()
    assert versions["fitted_with"] == read_header(name).recorded_versions()


def test_profiles_record_each_stage_and_the_check_knows_every_effects_stage() -> None:
    """Saved profiles carry each effect's stage; the check knows it without torch (the built-in table) and asks
    the registry for effects registered by other code (the tests' own)."""
    assert {name: effect_facts(name).stage for name in EFFECTS} == {name: cls.stage for name, cls in EFFECTS.items()}
    assert all("stage" in spec for spec in load_profile("city100-iphonex").metadata()["effects"])


@pytest.mark.parametrize("width", [0, 1, 64, MAX_WIDTH, MAX_WIDTH + 1, True, 2.0, "8", None])
def test_the_network_config_check_agrees_with_the_network(width) -> None:
    with torch.device("meta"):
        default = DomainShiftNet().width
    assert (MAX_WIDTH, default) == (MAX_NETWORK_WIDTH, DEFAULT_NETWORK_WIDTH)
    config = {"width": width}
    try:
        with torch.device("meta"):
            DomainShiftNet(**config)
    except ValueError as error:
        with pytest.raises(ValueError) as checked:
            check_network_config(config)
        assert str(checked.value) == str(error)
    else:
        check_network_config(config)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"network": {"arch": "DomainShiftNet", "config": {"width": 5000}}}, "width must be an integer from 1 to 1024"),
        ({"network": {"arch": "ResNet"}}, "metadata 'network' must be null or"),
        ({"effects": [{"name": "lens_flare", "config": {}}]}, "uses effect 'lens_flare', unknown to camdegrade"),
        ({"effects": [{"name": ["blur"], "config": {}}]}, "an effect's 'name' must be a string, got a list"),
        ({"effects": [{"name": "blur", "config": {}}] * 65}, "declares 65 effect stages"),
        ({"format_version": 7}, "newer than this camdegrade"),
        ({"format": "other"}, "is not a camdegrade profile"),
    ],
)
def test_info_refuses_what_load_profile_refuses(tmp_path: Path, change, message: str, capsys) -> None:
    path = profile_file(tmp_path / "bad.safetensors", deterministic_profile(), change)
    with pytest.raises(ProfileError, match=message):
        load_profile(path)
    status, _, err = run_cli(["info", path], capsys)
    assert status == 1
    assert message in one_line_error(err)


@pytest.mark.parametrize(
    ("header", "message"),
    [
        (b"{not json", "is corrupt or truncated"),
        (b'{"__metadata__": {"camdegrade": 3}}', "not a safetensors header"),
        (b'{"__metadata__": {"other": "x"}}', "not a camdegrade profile"),
        (b'{"x": {"dtype": "F32"}, "__metadata__": {"camdegrade": "{\\"format\\": \\"camdegrade-profile\\", '
         b'\\"format_version\\": 1}"}}', "lacks its dtype or shape"),
    ],
)  # fmt: skip
def test_info_refuses_damaged_headers_in_one_line(tmp_path: Path, header: bytes, message: str, capsys) -> None:
    path = tmp_path / "damaged.safetensors"
    path.write_bytes(len(header).to_bytes(8, "little") + header)
    status, _, err = run_cli(["info", path], capsys)
    assert status == 1 and message in one_line_error(err)


def test_a_header_longer_than_the_file_is_refused(tmp_path: Path, capsys) -> None:
    path = tmp_path / "short.safetensors"
    path.write_bytes((10**6).to_bytes(8, "little") + b'{"__metadata__": {}}')
    status, _, err = run_cli(["info", path], capsys)
    assert status == 1 and "not a safetensors file (bad or truncated header)" in one_line_error(err)


# --- versions ----------------------------------------------------------------------------------------------------

HERE = {"torch": "2.14.1", "torchvision": "0.29.1"}


@pytest.mark.parametrize(
    ("fitted", "warned"),
    [
        ({"torch": "2.3.0", "torchvision": "0.18.0"}, []),
        ({"torch": "1.13.1+cu117", "torchvision": "0.14.1"}, ["torch"]),
        ({"torch": "2.14.1", "torchvision": "1.0.0"}, ["torchvision"]),
        ({"machine": "x86_64, 2 threads, torch 1.12.0+cpu"}, ["torch"]),  # profiles fitted before the keys
        ({"machine": "x86_64, 2 threads, torch 2.14.1+cu130"}, []),
        ({}, []),
    ],
)
def test_info_warns_once_per_package_of_another_major_release(tmp_path, monkeypatch, capsys, fitted, warned) -> None:
    profile = deterministic_profile()
    profile.fitted = fitted
    path = profile.save(tmp_path / "old.safetensors")
    monkeypatch.setattr(metadata_module, "running_versions", lambda: dict(HERE))
    status, out, err = run_cli(["info", path], capsys)
    assert status == 0
    lines = err.strip().splitlines()
    assert len(lines) == len(warned)
    for package, line in zip(warned, lines, strict=True):
        assert line.startswith("camdegrade info: warning: profile 'test-deterministic' was fitted with")
        assert f"this is {package} {HERE[package]}, another major release" in line
    recorded = read_header(path).recorded_versions()
    assert f"versions   fitted with torch {recorded['torch'] or '(not recorded)'}, torchvision " in out
    assert "; running torch 2.14.1, torchvision 0.29.1" in out


def test_running_versions_are_the_installed_ones_read_without_importing() -> None:
    versions = running_versions()
    assert versions["torch"] is not None and torch.__version__.startswith(versions["torch"])
    import torchvision

    assert versions["torchvision"] is not None and torchvision.__version__.startswith(versions["torchvision"])
