"""Bad profiles (issue 17): metadata may not ask for huge allocations, tensors must be finite floats, every effect's
values must lie in its stated ranges, and only regular files are opened. Each refusal is one-line ProfileError."""

from __future__ import annotations

import os
import threading
from pathlib import Path

import pytest
import torch

from bad_inputs import profile_file
from camdegrade import CameraProfile, load_profile
from camdegrade.effects import EFFECTS, JPEG, Blur, Distortion, Noise, Tone, Vignetting
from camdegrade.errors import ProfileError
from profiles_for_tests import deterministic_profile, seeded_network
from test_effects import strong

#: The effects camdegrade registers (the test-only ones in profiles_for_tests are not held to its ranges).
MAX_WIDTH = 1024  # camdegrade.network.MAX_WIDTH
REGISTERED = sorted(name for name, cls in EFFECTS.items() if cls.__module__.startswith("camdegrade."))


def _one_line(error: pytest.ExceptionInfo) -> str:
    text = str(error.value)
    assert "\n" not in text, text
    return text


@pytest.mark.parametrize("width", [10**6, 3000, MAX_WIDTH + 1])
def test_a_huge_network_width_is_refused_before_allocating(
    tmp_path: Path, width: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = profile_file(
        tmp_path / "wide.safetensors",
        deterministic_profile(),
        {"network": {"arch": "DomainShiftNet", "config": {"width": width}}},
    )
    layers = []
    original = torch.nn.Conv2d.__init__

    def counting_init(self: torch.nn.Conv2d, *args: object, **kwargs: object) -> None:
        layers.append(args)
        original(self, *args, **kwargs)

    monkeypatch.setattr(torch.nn.Conv2d, "__init__", counting_init)
    with pytest.raises(ProfileError, match=rf"width must be an integer from 1 to {MAX_WIDTH}, got width={width}"):
        load_profile(path)
    assert layers == []  # no layer of the asked width was built


def test_a_width_that_does_not_match_the_tensors_is_listed(tmp_path: Path) -> None:
    """Compared with the file's header (the network is built without memory until the shapes match)."""
    path = profile_file(
        tmp_path / "w.safetensors",
        deterministic_profile(),
        {"network": {"arch": "DomainShiftNet", "config": {"width": 96}}},
    )
    with pytest.raises(ProfileError, match=r"wrong shapes: network\.decode1\.bias \(64,\) \(expected \(96,\)\)"):
        load_profile(path)


def _noise_profile() -> CameraProfile:
    return CameraProfile(seeded_network(), [Noise(0.01, 1e-4), Distortion(0.05), Vignetting(-0.3)], name="n")


@pytest.mark.parametrize(
    "key, value, message",
    [
        ("effects.0.a", torch.tensor([float("nan"), 0.01, 0.01]), r"noise\): a must be finite, got a=\[nan, "),
        ("effects.0.b", torch.tensor([1e-4, float("inf"), 1e-4]), r"noise\): b must be finite, got b=\[.*inf"),
        ("effects.1.k1", torch.tensor(float("nan")), r"distortion\): k1 must be .*got k1=nan"),
        ("effects.2.k1", torch.tensor(1e30), r"vignetting\): k1 must be from -10 to 10, got k1=1e\+30"),
        ("network.encode1.weight", None, r"network\.encode1\.weight must be finite"),
    ],
)
def test_non_finite_and_out_of_range_values_are_refused(tmp_path: Path, key: str, value, message: str) -> None:
    profile = _noise_profile()
    if value is None:
        value = profile.state_dict()[key].clone()
        value.view(-1)[5] = float("nan")
    path = profile_file(tmp_path / "bad.safetensors", profile, tensors={key: value})
    with pytest.raises(ProfileError, match=message) as info:
        load_profile(path)
    assert _one_line(info).startswith(f"profile {str(path)!r}")


def test_integer_network_weights_are_refused(tmp_path: Path) -> None:
    profile = deterministic_profile()
    weights = {key: value.mul(100).round().to(torch.int32) for key, value in profile.state_dict().items()}
    path = profile_file(tmp_path / "int.safetensors", profile, tensors=weights)
    with pytest.raises(ProfileError, match=r"network\.\w+\.\w+ has dtype int32, expected float32 or float64") as info:
        load_profile(path)
    _one_line(info)


@pytest.mark.parametrize("version", [-7, 0])
def test_a_format_version_below_one_is_refused(tmp_path: Path, version: int) -> None:
    path = profile_file(tmp_path / "v.safetensors", deterministic_profile(), {"format_version": version})
    with pytest.raises(ProfileError, match=rf"format_version {version}, expected an integer from 1 to"):
        load_profile(path)


@pytest.mark.parametrize(
    "effects, message",
    [
        ([{"name": "blur", "config": {"sigma_jitter": 1e9}}], r"blur\): sigma_jitter must be from 0 to"),
        ([{"name": "jpeg", "config": {"quality_jitter": 10**9}}], r"jpeg\): quality_jitter must be"),
        ([{"name": "tone", "config": {"exposure_jitter": 1e6}}], r"tone\): exposure_jitter must be from 0 to"),
    ],
)
def test_effect_configs_are_bounded(tmp_path: Path, effects, message: str) -> None:
    chain = [EFFECTS[spec["name"]]() for spec in effects]
    path = profile_file(tmp_path / "c.safetensors", CameraProfile(None, chain), {"effects": effects})
    with pytest.raises(ProfileError, match=message):
        load_profile(path)


def test_a_blur_too_wide_to_compute_is_refused(tmp_path: Path) -> None:
    path = profile_file(
        tmp_path / "b.safetensors", CameraProfile(None, [Blur(1.0)]), tensors={"effects.0.sigma_x": torch.tensor(1e6)}
    )
    with pytest.raises(ProfileError, match=r"blur\): sigma_x must be from 0 to \d+"):
        load_profile(path)


@pytest.mark.parametrize(
    "effect, key, value, message",
    [
        (JPEG(80), "quality", 0.0, r"quality must be an integer from 1 to 100, got quality=0"),
        (JPEG(80), "quality", 55.5, r"quality must be an integer from 1 to 100, got quality=55.5"),
        (Tone(1.1), "gamma", -1.0, r"gamma must be from 0 \(exclusive\) to \d+, got gamma=-1"),
        (Tone(1.1), "white", -0.5, r"white must be greater than black, got black=0, white=-0.5"),
        (Blur(1.0), "sigma_y", -2.0, r"sigma_y must be from 0 to \d+, got sigma_y=-2"),
    ],
)
def test_each_effect_checks_its_own_ranges_at_load(
    tmp_path: Path, effect, key: str, value: float, message: str
) -> None:
    path = profile_file(
        tmp_path / "r.safetensors", CameraProfile(None, [effect]), tensors={f"effects.0.{key}": torch.tensor(value)}
    )
    with pytest.raises(ProfileError, match=message):
        load_profile(path)


@pytest.mark.parametrize("name", REGISTERED)
def test_fitted_and_neutral_values_pass_the_check(name: str) -> None:
    strong(name).check_values()
    EFFECTS[name].neutral().check_values()


@pytest.mark.parametrize("name", REGISTERED)
def test_every_effect_refuses_a_nan_in_any_of_its_values(name: str) -> None:
    for key, _ in strong(name).named_buffers():
        effect = strong(name)
        getattr(effect, key).view(-1)[0] = float("nan")
        with pytest.raises(ValueError, match=rf"{key} must be "):
            effect.check_values()


def test_saving_refuses_values_that_could_not_be_loaded(tmp_path: Path) -> None:
    vignetting = Vignetting(-0.3)
    vignetting.k1.fill_(1e30)
    with pytest.raises(ValueError, match=r"vignetting\): k1 must be from -10 to 10"):
        CameraProfile(None, [vignetting]).save(tmp_path / "v.safetensors")
    assert not (tmp_path / "v.safetensors").exists()


def test_a_half_precision_profile_saves_as_float32_and_loads(tmp_path: Path) -> None:
    profile = deterministic_profile().half()
    loaded = load_profile(profile.save(tmp_path / "half.safetensors"))
    assert all(value.dtype == torch.float32 for value in loaded.state_dict().values())


def test_a_device_file_is_not_a_regular_file() -> None:
    if not Path("/dev/zero").exists():
        pytest.skip("no /dev/zero here")
    with pytest.raises(ProfileError, match=r"'/dev/zero' is not a regular file"):
        load_profile("/dev/zero")


def test_a_folder_is_named_as_a_folder(tmp_path: Path) -> None:
    with pytest.raises(ProfileError, match=r"is a folder, not a profile file"):
        load_profile(tmp_path)


def test_a_fifo_is_refused_without_blocking(tmp_path: Path) -> None:
    fifo = tmp_path / "pipe.safetensors"
    os.mkfifo(fifo)
    outcome: list[BaseException | None] = []

    def load() -> None:
        try:
            load_profile(fifo)
            outcome.append(None)
        except BaseException as error:  # recorded for the main thread
            outcome.append(error)

    thread = threading.Thread(target=load, daemon=True)
    thread.start()
    thread.join(timeout=10)
    if thread.is_alive():  # unblock the reader so the test run can end, then fail
        os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
        thread.join(timeout=10)
        pytest.fail("load_profile blocked on a FIFO")
    assert isinstance(outcome[0], ProfileError) and "is not a regular file" in str(outcome[0])


@pytest.mark.parametrize(
    "name, config, error, message",
    [
        ("jpeg", {"quality_jitter": float("inf")}, ValueError, "quality_jitter must be a non-negative integer"),
        ("noise", {"knots": float("inf")}, ValueError, "knots must be a whole number, got knots=inf"),
        ("noise", {"taps": float("nan")}, ValueError, "taps must be a whole number, got taps=nan"),
        ("noise", {"knots": "8"}, ValueError, "knots must be a whole number, got knots='8'"),
        ("noise", {"columns": "false"}, TypeError, "columns must be True or False, got columns='false'"),
        ("noise", {"mixing": 1}, TypeError, "mixing must be True or False, got mixing=1"),
    ],
)
def test_effect_configs_refuse_infinity_and_text_themselves(name: str, config: dict, error: type, message: str) -> None:
    """Built from a config without a profile file (no file check before them): Infinity used to escape as an
    OverflowError, the text "false" to switch a part on."""
    with pytest.raises(error, match=message):
        EFFECTS[name].from_config(config)


def test_an_integer_too_long_to_read_is_a_profile_error(tmp_path: Path) -> None:
    """Python refuses to read integers of more than 4300 digits: that ValueError escaped as such."""
    path = CameraProfile(None, [JPEG(80)]).save(tmp_path / "j.safetensors")
    data = path.read_bytes()
    start = data.index(b'quality_jitter\\":0') + len(b'quality_jitter\\":')
    long = data[:start] + b"9" * 5000 + data[start + 1 :]
    length = int.from_bytes(long[:8], "little") + 4999
    path.write_bytes(length.to_bytes(8, "little") + long[8:])
    with pytest.raises(ProfileError, match="has invalid JSON metadata: Exceeds the limit"):
        load_profile(path)
