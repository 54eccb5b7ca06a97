"""``camdegrade info`` refuses what ``load_profile`` refuses (issue 26): one torch-free check of a profile file.

Each case corrupts a copy of a built-in profile file the way the issue lists (an unknown effect with a stage key, a
width that disagrees with the tensors, non-finite or out-of-range values, relabelled dtypes, swapped shapes, unknown
config keys, extra tensors, a stage recorded under the wrong kind, Infinity or NaN in a config, a string for a
boolean); both readers must refuse it with a one-line ProfileError naming what is wrong. Then the torch-free table
of effect facts is held to the effect classes: every effect, every key, every range.
"""

from __future__ import annotations

import copy
import json
import math
import struct
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from bad_inputs import one_line_error, run_cli
from camdegrade import CameraProfile, list_profiles, load_profile
from camdegrade import network as network_module
from camdegrade._profile_format.effect_facts import BUILT_IN, Bound
from camdegrade._profile_format.header import read_header
from camdegrade._profile_format.network_entry import FIELD_CHANNELS, LINEAR_TAPS, NETWORK_CLASSES, network_shapes
from camdegrade.effects import EFFECTS, JPEG, Effect, Noise, Tone
from camdegrade.errors import ProfileError
from camdegrade.network import ARCHITECTURES
from camdegrade.profile import METADATA_KEY, builtin_profiles_dir
from conftest import PAPER_BUILT_IN
from test_effects import REGISTERED, strong

# --- a profile file taken apart and put together again ------------------------------------------------------------


class ProfileParts:
    """A profile file's header (tensor entries), metadata and data bytes, to corrupt and write back."""

    def __init__(self, path: Path) -> None:
        data = path.read_bytes()
        length = int.from_bytes(data[:8], "little")
        self.header: dict[str, Any] = json.loads(data[8 : 8 + length])
        self.metadata: dict[str, Any] = json.loads(self.header.pop("__metadata__")[METADATA_KEY])
        self.body = bytearray(data[8 + length :])

    def write(self, path: Path) -> Path:
        text = json.dumps(self.metadata, sort_keys=True, separators=(",", ":"))  # Infinity and NaN as JSON allows
        header = json.dumps({**self.header, "__metadata__": {METADATA_KEY: text}}).encode()
        header += b" " * (-len(header) % 8)
        path.write_bytes(len(header).to_bytes(8, "little") + header + bytes(self.body))
        return path

    def set_values(self, key: str, *values: float) -> None:
        """Overwrite the first values of float32 tensor ``key`` in place."""
        start = self.header[key]["data_offsets"][0]
        self.body[start : start + 4 * len(values)] = struct.pack(f"<{len(values)}f", *values)

    def values(self, key: str) -> np.ndarray:
        start, stop = self.header[key]["data_offsets"]
        return np.frombuffer(bytes(self.body[start:stop]), dtype="<f4").reshape(self.header[key]["shape"])

    def add_tensor(self, key: str, values: list[float], shape: list[int]) -> None:
        end = len(self.body)
        self.body += struct.pack(f"<{len(values)}f", *values)
        self.header[key] = {"dtype": "F32", "shape": shape, "data_offsets": [end, len(self.body)]}

    def add_jpeg(self, quality: float, **config: Any) -> None:
        """A JPEG stage appended to the chain (the built-ins have none), with its one tensor."""
        index = len(self.metadata["effects"])
        config = {"quality_jitter": 0, "probability": 1.0, **config}
        self.metadata["effects"].append({"name": "jpeg", "stage": "codec", "config": config})
        self.add_tensor(f"effects.{index}.quality", [quality], [])


def _effects(parts: ProfileParts) -> list[dict[str, Any]]:
    return parts.metadata["effects"]


def _scale_row(parts: ProfileParts, key: str, factor: float) -> None:
    rows = parts.values(key).copy()
    parts.set_values(key, *(rows[0] * factor), *rows[1:].reshape(-1))


#: (case, built-in profile or file, corruption, message naming what is wrong). PAPER_BUILT_IN: blur, noise, tone
#: (width 64); lowcost-robot-sim: distortion, blur, noise, sharpen.
Corruption = Callable[[ProfileParts], None]
CASES: list[tuple[str, str | Path, Corruption, str]] = [
    (
        "unknown-effect-with-a-stage-key",
        PAPER_BUILT_IN,
        lambda p: _effects(p)[0].update(name="lens_flare"),
        "uses effect 'lens_flare', unknown to camdegrade",
    ),
    (
        "width-disagrees-with-the-tensors",
        PAPER_BUILT_IN,
        lambda p: p.metadata["network"]["config"].update(width=32),
        "wrong shapes: network.decode1.bias (64,) (expected (32,))",
    ),
    (
        "width-disagrees-narrower-file",
        "city100-iphonex-fast",
        lambda p: p.metadata["network"]["config"].update(width=64),
        "wrong shapes: network.decode1.bias (32,) (expected (64,))",
    ),
    (
        "nan-effect-value",
        PAPER_BUILT_IN,
        lambda p: p.set_values("effects.0.sigma_x", math.nan),
        "effect 0 (blur): sigma_x must be finite, got sigma_x=nan",
    ),
    (
        "infinite-effect-value",
        "lowcost-robot-sim",
        lambda p: p.set_values("effects.1.levels", math.inf),
        "effect 1 (noise): levels must be finite, got levels=[inf, ",
    ),
    (
        "infinite-network-weight",
        PAPER_BUILT_IN,
        lambda p: p.set_values("network.encode1.weight", math.inf),
        "network.encode1.weight must be finite, got 1 NaN or infinite values",
    ),
    (
        "out-of-range-effect-value",
        PAPER_BUILT_IN,
        lambda p: p.set_values("effects.2.gamma", 100.0),
        "effect 2 (tone): gamma must be from 0 (exclusive) to 16, got gamma=100",
    ),
    (
        "out-of-range-distortion",
        "lowcost-robot-sim",
        lambda p: p.set_values("effects.0.k1", -3.0),
        "effect 0 (distortion): k1 must be from -2 to 2, got k1=-3",
    ),
    (
        "noise-kernel-rows-not-unit-norm",
        PAPER_BUILT_IN,
        lambda p: _scale_row(p, "effects.1.across", 1.5),
        "effect 1 (noise): every row of across must have unit norm",
    ),
    (
        "white-level-below-black",
        PAPER_BUILT_IN,
        lambda p: p.set_values("effects.2.white", -1.0),
        "effect 2 (tone): white must be greater than black",
    ),
    (
        "jpeg-quality-not-a-whole-number",
        "lowcost-robot-sim",
        lambda p: p.add_jpeg(55.5),
        "effect 4 (jpeg): quality must be an integer from 1 to 100, got quality=55.5",
    ),
    (
        "dtype-relabelled-same-size",
        PAPER_BUILT_IN,
        lambda p: p.header["effects.0.sigma_x"].update(dtype="I32"),
        "wrong dtypes: effects.0.sigma_x has dtype int32, expected float32 or float64",
    ),
    (
        "dtype-relabelled-other-size",
        PAPER_BUILT_IN,
        lambda p: p.header["effects.1.a"].update(dtype="F64"),
        "tensor 'effects.1.a' holds 12 bytes, but 3 values of dtype float64 take 24",
    ),
    (
        "dtype-relabelled-with-its-shape",
        PAPER_BUILT_IN,
        lambda p: p.header["effects.1.a"].update(dtype="BF16", shape=[6]),
        "wrong shapes: effects.1.a (6,) (expected (3,)); wrong dtypes: effects.1.a has dtype bfloat16",
    ),
    (
        "network-weight-relabelled",
        "lowcost-robot-sim",
        lambda p: p.header["network.decode2.bias"].update(dtype="U32"),
        "wrong dtypes: network.decode2.bias has dtype uint32",
    ),
    (
        "shape-swapped",
        PAPER_BUILT_IN,
        lambda p: p.header["effects.1.across"].update(shape=[5, 3]),
        "wrong shapes: effects.1.across (5, 3) (expected (3, 5))",
    ),
    (
        "network-shape-swapped",
        PAPER_BUILT_IN,
        lambda p: p.header["network.encode1.weight"].update(shape=[3, 64, 3, 3]),
        "wrong shapes: network.encode1.weight (3, 64, 3, 3) (expected (64, 3, 3, 3))",
    ),
    (
        "unknown-config-key",
        PAPER_BUILT_IN,
        lambda p: _effects(p)[0]["config"].update(radius=2),
        "effect 0 (blur): unknown config keys ['radius']",
    ),
    (
        "constructor-argument-as-config-key",
        "lowcost-robot-sim",
        lambda p: _effects(p)[0]["config"].update(k1=0.5),
        "effect 0 (distortion): unknown config keys ['k1']",
    ),
    (
        "unknown-key-in-an-effect-entry",
        PAPER_BUILT_IN,
        lambda p: _effects(p)[2].update(strength=0.5),
        "effect 2 (tone) has unknown keys ['strength']",
    ),
    (
        "extra-effect-tensor",
        PAPER_BUILT_IN,
        lambda p: p.add_tensor("effects.0.extra", [0.0], [1]),
        "unexpected tensors: effects.0.extra",
    ),
    (
        "extra-tensor-of-no-stage",
        "lowcost-robot-sim",
        lambda p: p.add_tensor("optimizer.step", [3.0], []),
        "unexpected tensors: optimizer.step",
    ),
    (
        "stage-recorded-under-the-wrong-kind",
        PAPER_BUILT_IN,
        lambda p: _effects(p)[0].update(stage="codec"),
        "effect 0 (blur) is recorded at stage 'codec', but blur belongs to stage 'optics'",
    ),
    (
        "infinity-knots",
        PAPER_BUILT_IN,
        lambda p: _effects(p)[1]["config"].update(knots=math.inf),
        "effect 1 (noise): knots must be an integer from 0 to 64, got knots=inf",
    ),
    (
        "infinity-quality-jitter",
        "lowcost-robot-sim",
        lambda p: p.add_jpeg(80.0, quality_jitter=math.inf),
        "effect 4 (jpeg): quality_jitter must be an integer from 0 to 99, got quality_jitter=inf",
    ),
    (
        "nan-gain-jitter",
        PAPER_BUILT_IN,
        lambda p: _effects(p)[1]["config"].update(gain_jitter=math.nan),
        "effect 1 (noise): gain_jitter must be from 0 to 2, got gain_jitter=nan",
    ),
    (
        "whole-number-knots-written-as-text",
        PAPER_BUILT_IN,
        lambda p: _effects(p)[1]["config"].update(knots="8"),
        "effect 1 (noise): config 'knots' must be an integer from 0 to 64, got a string '8'",
    ),
    (
        "string-false-for-a-boolean",
        PAPER_BUILT_IN,
        lambda p: _effects(p)[0]["config"].update(linear="false"),
        "effect 0 (blur): config 'linear' must be true or false, got a string 'false'",
    ),
    (
        "string-false-for-noise-columns",
        "lowcost-robot-sim",
        lambda p: _effects(p)[1]["config"].update(columns="false"),
        "effect 1 (noise): config 'columns' must be true or false, got a string 'false'",
    ),
]


def _corrupted(tmp_path: Path, builtin: str | Path, corrupt: Corruption) -> Path:
    source = builtin if isinstance(builtin, Path) else builtin_profiles_dir() / f"{builtin}.safetensors"
    parts = ProfileParts(source)
    corrupt(parts)
    return parts.write(tmp_path / f"{source.stem}-corrupted.safetensors")


@pytest.mark.parametrize(("builtin", "corrupt", "message"), [case[1:] for case in CASES], ids=[c[0] for c in CASES])
def test_info_and_load_profile_refuse_the_same_corrupted_file(
    tmp_path: Path, builtin: str | Path, corrupt: Corruption, message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    path = _corrupted(tmp_path, builtin, corrupt)
    with pytest.raises(ProfileError) as loaded:
        load_profile(path)
    assert message in str(loaded.value) and "\n" not in str(loaded.value)
    assert str(loaded.value).startswith(f"profile {str(path)!r}") or str(loaded.value).startswith(
        f"profile file {str(path)!r}"
    )
    status, out, err = run_cli(["info", path], capsys)
    assert status == 1 and out == ""
    assert one_line_error(err) == f"camdegrade: error: {loaded.value}"


@pytest.mark.parametrize("case", ["string-false-for-a-boolean", "whole-number-knots-written-as-text"])
def test_a_value_of_the_wrong_json_type_is_a_type_error(tmp_path: Path, case: str) -> None:
    _, builtin, corrupt, _ = next(entry for entry in CASES if entry[0] == case)
    with pytest.raises(TypeError):
        load_profile(_corrupted(tmp_path, builtin, corrupt))


HUGE = 100_000
#: Metadata a file can make as large as it likes, in every place an error quotes it.
HUGE_METADATA: dict[str, Corruption] = {
    "network": lambda p: p.metadata.update(network=list(range(HUGE))),
    "network-config-keys": lambda p: p.metadata["network"].update(config={f"k{i}": i for i in range(HUGE)}),
    "width": lambda p: p.metadata["network"]["config"].update(width="x" * HUGE),
    "effect-entry": lambda p: _effects(p).__setitem__(0, list(range(HUGE))),
    "effect-entry-keys": lambda p: _effects(p)[0].update({f"k{i}": i for i in range(HUGE)}),
    "effect-name": lambda p: _effects(p)[0].update(name="x" * HUGE),
    "stage": lambda p: _effects(p)[0].update(stage="x" * HUGE),
    "config-keys": lambda p: _effects(p)[0]["config"].update({f"k{i}": i for i in range(HUGE)}),
    "format-version": lambda p: p.metadata.update(format_version="x" * HUGE),
    "format-version-number": lambda p: p.metadata.update(format_version=10**4000),
    "tensor-name": lambda p: p.add_tensor("x" * HUGE, [0.0], []),
    "tensor-dtype": lambda p: p.header["effects.0.k1"].update(dtype="x" * HUGE),
    "tensor-shape": lambda p: p.header["effects.0.k1"].update(shape=[2**62] * 300),
}


@pytest.mark.parametrize("corrupt", HUGE_METADATA.values(), ids=HUGE_METADATA.keys())
def test_errors_quote_huge_metadata_shortened(tmp_path: Path, corrupt: Corruption) -> None:
    """A file's metadata is the attacker's to size: the one-line error quotes it in at most a few hundred
    characters (80 per value, 10 names per list), never whole."""
    path = _corrupted(tmp_path, "lowcost-robot-sim", corrupt)
    for read in (load_profile, lambda path: read_header(path).describe()):
        with pytest.raises(ProfileError) as refused:
            read(path)
        assert len(str(refused.value)) < 400 + len(str(path)), str(refused.value)[:400]


def test_a_safetensors_file_of_other_metadata_is_named_shortly(tmp_path: Path) -> None:
    header = json.dumps({"__metadata__": {f"key{i}": "" for i in range(HUGE)}}).encode()
    path = tmp_path / "other.safetensors"
    path.write_bytes(len(header).to_bytes(8, "little") + header)
    for read in (load_profile, read_header):
        with pytest.raises(ProfileError, match="not a camdegrade profile") as refused:
            read(path)
        assert len(str(refused.value)) < 400 + len(str(path))


@pytest.mark.parametrize("name", list_profiles())
def test_every_built_in_profile_passes_both(tmp_path: Path, name: str, capsys: pytest.CaptureFixture[str]) -> None:
    """The built-ins, and their copies through this test's reader and writer (so that what the cases above refuse
    is their corruption, not the copying)."""
    copied = _corrupted(tmp_path, name, lambda parts: None)
    for profile in (name, copied):
        status, out, err = run_cli(["info", profile], capsys)
        assert (status, err) == (0, "") and out.startswith(f"profile    {name}\n")
        loaded = load_profile(profile)
        assert loaded.name == name
    for key, value in load_profile(name).state_dict().items():
        assert torch.equal(loaded.state_dict()[key], value)


# --- Infinity, NaN and text in every config value of every effect -------------------------------------------------


def _config_values() -> list[tuple[str, str, Any]]:
    """Every config key of every registered effect (as its fullest instances write it) with a bad value: Infinity
    and NaN for a number, the text "false" for a boolean."""
    cases = []
    for name in REGISTERED:
        for key, value in {**_full(name).config(), **strong(name).config()}.items():
            bad = ["false"] if isinstance(value, bool) else [math.inf, -math.inf, math.nan]
            cases += [(name, key, choice) for choice in bad]
    return cases


def _full(name: str) -> Effect:
    """The effect with every optional part (a noise stage with a level table, kernels, columns and mixing)."""
    if name == "noise":
        return load_profile(PAPER_BUILT_IN).effects[1]
    if name == "tone":  # a local curve: its base layer is written only where it is one
        return Tone(1.2, 0.03, 0.95, 0.2, exposure_jitter=0.3, base_sigma=3.0)
    return strong(name)


@pytest.mark.parametrize(("name", "key", "value"), _config_values())
def test_infinity_nan_and_text_in_any_effect_config_are_refused_at_load(
    tmp_path: Path, name: str, key: str, value: Any, capsys: pytest.CaptureFixture[str]
) -> None:
    effect = _full(name)
    spec = {"name": name, "stage": effect.stage, "config": {**effect.config(), key: value}}
    path = tmp_path / "c.safetensors"
    CameraProfile(None, [effect]).save(path)
    parts = ProfileParts(path)
    parts.metadata["effects"] = [spec]
    parts.write(path)
    expected = TypeError if isinstance(value, str) else ValueError
    with pytest.raises(ProfileError, match=rf"effect 0 \({name}\): (config '{key}'|{key}) must be ") as refused:
        load_profile(path)
    assert isinstance(refused.value, expected)
    status, _, err = run_cli(["info", path], capsys)
    assert status == 1 and one_line_error(err) == f"camdegrade: error: {refused.value}"


def test_a_profile_with_a_jpeg_stage_of_infinite_jitter_never_reaches_apply(tmp_path: Path) -> None:
    """It used to load as far as ``int(inf)``: an OverflowError (not a ProfileError) and a traceback."""
    profile = CameraProfile(None, [JPEG(80)])
    path = profile.save(tmp_path / "j.safetensors")
    parts = ProfileParts(path)
    parts.metadata["effects"][0]["config"]["quality_jitter"] = math.inf
    with pytest.raises(ProfileError, match="quality_jitter must be an integer from 0 to 99, got quality_jitter=inf"):
        load_profile(parts.write(path))


# --- the torch-free table against the effect classes --------------------------------------------------------------


def test_noise_full_instance_has_every_optional_part() -> None:
    noise = _full("noise")
    assert isinstance(noise, Noise) and noise.knots and noise.taps
    assert {"column_sigma", "mixing", "levels", "across"} <= set(dict(noise.named_buffers()))


def test_the_table_holds_every_registered_effect_at_its_stage() -> None:
    assert sorted(BUILT_IN) == REGISTERED
    for name in REGISTERED:
        assert BUILT_IN[name].stage == EFFECTS[name].stage, name


def _instances(name: str) -> list[Effect]:
    """The effect as its class builds it by default, neutral, strong, and as the built-in profiles hold it."""
    cls = EFFECTS[name]
    built_in = [
        effect for profile in list_profiles() for effect in load_profile(profile).effects if effect.name == name
    ]
    return [cls.from_config({}), cls.neutral(), strong(name), _full(name), *built_in]


@pytest.mark.parametrize("name", REGISTERED)
def test_the_table_knows_every_config_key_its_type_and_every_tensor_shape(name: str) -> None:
    facts = BUILT_IN[name]
    written: set[str] = set()
    for effect in _instances(name):
        config = json.loads(json.dumps(effect.config()))
        written |= set(config)
        filled = facts.check_config(config)
        for key, value in config.items():
            assert isinstance(value, bool) == (facts.settings[key].kind is bool), (name, key)
        shapes = {key: tuple(value.shape) for key, value in effect.state_dict().items()}
        assert facts.tensor_shapes(filled) == shapes, name
        assert all(value.is_floating_point() for value in effect.state_dict().values())
    assert written == set(facts.settings), name  # no key the class writes is unknown, none in the table unused
    defaults = EFFECTS[name].from_config({})
    filled = facts.check_config({})
    assert {key: filled[key] for key in defaults.config()} == defaults.config()
    with pytest.raises(TypeError):
        EFFECTS[name].from_config({"no_such_key": 1})


def _probes(bound: Bound | None, integer: bool = False) -> list[float]:
    """Values on, just inside and just outside ``bound`` (finite values far out where there is none)."""
    extremes = [math.nan, math.inf, -math.inf]
    if bound is None:
        return [0.0, -1e30, 1e30, *extremes]
    step = 1.0 if integer else max(abs(bound.low), abs(bound.high), 1.0) * 1e-3
    inside = [bound.low + step, bound.high - step, (bound.low + bound.high) / 2]
    return [bound.low, bound.high, bound.low - step, bound.high + step, *inside, *extremes]


def _class_accepts_values(effect: Effect) -> bool:
    try:
        effect.check_values()
    except ValueError:
        return False
    return True


def _table_accepts_values(name: str, effect: Effect) -> bool:
    arrays = {key: value.numpy() for key, value in effect.state_dict().items()}
    try:
        BUILT_IN[name].check_values(BUILT_IN[name].check_config(effect.config()), arrays)
    except ValueError:
        return False
    return True


@pytest.mark.parametrize("name", REGISTERED)
def test_the_table_and_the_class_accept_the_same_tensor_values(name: str) -> None:
    """Every tensor of every instance set to each probe of its range (and rows of unit-norm tensors scaled a
    little): the class's check_values and the table agree on every one."""
    facts, compared = BUILT_IN[name], 0
    for effect in _instances(name):
        for key in effect.state_dict():
            buffer = facts.buffers[key]
            probes = _probes(buffer.bound, integer=bool(buffer.bound and buffer.bound.integer))
            changes = [lambda v, x=x: v.fill_(x) for x in probes]
            if buffer.unit_rows:
                changes += [lambda v, f=f: v.mul_(f) for f in (1.0, 1.0005, 0.9995, 1.002, 0.99)]
            for change in changes:
                probe = copy.deepcopy(effect)
                change(getattr(probe, key))
                assert _class_accepts_values(probe) == _table_accepts_values(name, probe), (name, key, probe)
                compared += 1
    assert compared >= 10


@pytest.mark.parametrize("name", REGISTERED)
def test_the_table_and_the_class_accept_the_same_values_drawn_together(name: str) -> None:
    """Random values for several tensors at once (rules between values: white above black)."""
    generator = torch.Generator().manual_seed(26)
    accepted = refused = 0
    for effect in _instances(name):
        for _ in range(25):
            probe = copy.deepcopy(effect)
            for key, value in probe.state_dict().items():
                bound = BUILT_IN[name].buffers[key].bound
                if bound is None or bool(torch.rand((), generator=generator) < 0.4):
                    continue
                span = bound.high - bound.low
                draw = torch.rand(value.shape, generator=generator, dtype=torch.float64) * 1.2 * span
                getattr(probe, key).copy_(draw + bound.low - 0.1 * span)
            agreed = _class_accepts_values(probe)
            assert agreed == _table_accepts_values(name, probe), (name, probe)
            accepted, refused = accepted + agreed, refused + (not agreed)
    assert accepted > 0 and refused > 0


def _class_accepts_config(name: str, config: dict[str, Any]) -> bool:
    try:
        effect = EFFECTS[name].from_config(config)
    except (TypeError, ValueError):
        return False
    return _class_accepts_values(effect)


def _table_accepts_config(name: str, config: dict[str, Any]) -> bool:
    try:
        BUILT_IN[name].check_config(config)
    except (TypeError, ValueError):
        return False
    return True


@pytest.mark.parametrize("name", REGISTERED)
def test_the_table_and_the_class_accept_the_same_config_values(name: str) -> None:
    """Every config key of the table, set to each probe of its range: construction plus check_values agree with
    the table. (The table is stricter about JSON types: a whole number written 2.0, or "false" for a boolean, is
    refused by the table and taken by the class, so only values of the right type are compared here.)"""
    facts, compared = BUILT_IN[name], 0
    for effect in _instances(name):
        config = effect.config()
        for key, setting in facts.settings.items():
            if setting.kind is bool:
                values: list[Any] = [True, False]
            elif setting.kind is int:
                values = [int(x) for x in _probes(setting.bound, integer=True) if math.isfinite(x)]
                values += [value + 1 for value in values]  # odd and even (taps)
            else:
                values = _probes(setting.bound)
            for value in values:
                probe = {**config, key: value}
                assert _class_accepts_config(name, probe) == _table_accepts_config(name, probe), (name, key, value)
                compared += 1
    assert compared >= len(facts.settings)


@pytest.mark.parametrize("arch", list(ARCHITECTURES))
@pytest.mark.parametrize("width", [1, 3, 64, 1024])
def test_the_network_shapes_are_the_networks(width: int, arch: str) -> None:
    with torch.device("meta"):
        network = ARCHITECTURES[arch](width)
    shapes = {f"network.{key}": tuple(value.shape) for key, value in network.state_dict().items()}
    assert network_shapes(width, type(network).__name__) == shapes


def test_the_format_knows_every_network_class_and_its_constants() -> None:
    assert tuple(cls.__name__ for cls in ARCHITECTURES.values()) == NETWORK_CLASSES
    assert (LINEAR_TAPS, FIELD_CHANNELS) == (network_module.LINEAR_TAPS, network_module.FIELD_CHANNELS)


def test_info_refuses_without_importing_torch(tmp_path: Path) -> None:
    """The refusals are decided by the torch-free check: a `camdegrade info` process imports no torch for them."""
    paths = []
    for case in ("unknown-effect-with-a-stage-key", "out-of-range-effect-value", "string-false-for-a-boolean"):
        _, builtin, corrupt, _ = next(entry for entry in CASES if entry[0] == case)
        (tmp_path / case).mkdir()
        paths.append(str(_corrupted(tmp_path / case, builtin, corrupt)))
    code = f"""
import contextlib, io, json, sys
from camdegrade.__main__ import main
statuses = []
for path in {paths!r}:
    with contextlib.redirect_stderr(io.StringIO()):
        statuses.append(main(["info", path]))
print(json.dumps([statuses, [name for name in ("torch", "torchvision") if name in sys.modules]]))
"""
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert run.returncode == 0, run.stderr
    assert json.loads(run.stdout) == [[1, 1, 1], []]
