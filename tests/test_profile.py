"""CameraProfile: safetensors round trip, strict loading, refusal of pickles, built-in registry."""

from __future__ import annotations

import json
import os
import pickle
import re

import pytest
import torch
from safetensors.torch import load_file, save_file

from camdegrade import (
    CameraDegrade,
    CameraProfile,
    ProfileError,
    UnknownProfileError,
    list_profiles,
    load_profile,
)
from camdegrade.profile import FORMAT_VERSION, serialize_metadata
from profiles_for_tests import AdditiveTestNoise, deterministic_profile, seeded_network, stochastic_profile


def image_batch(seed: int = 0) -> torch.Tensor:
    return torch.randint(0, 256, (2, 3, 24, 20), dtype=torch.uint8, generator=torch.Generator().manual_seed(seed))


def test_round_trip_keeps_weights_chain_and_metadata(tmp_path):
    profile = stochastic_profile()
    profile.fitted = {"pairs": 12, "epochs": 3}
    profile.quality = {"held_out_psnr_db": 27.5}
    path = profile.save(tmp_path / "p.safetensors")
    loaded = load_profile(path)
    assert loaded.name == profile.name and loaded.effect_names == ["test_additive_noise"]
    assert loaded.fitted == {"pairs": 12, "epochs": 3} and loaded.quality == {"held_out_psnr_db": 27.5}
    for key, value in profile.state_dict().items():
        assert torch.equal(loaded.state_dict()[key], value)


def test_non_empty_chain_degrades_identically_after_reload(tmp_path):
    profile = stochastic_profile()
    loaded = load_profile(profile.save(tmp_path / "p.safetensors"))
    images = image_batch()
    assert torch.equal(CameraDegrade(profile, seed=4)(images), CameraDegrade(loaded, seed=4)(images))


def test_saved_file_is_plain_safetensors_with_json_metadata(tmp_path):
    path = deterministic_profile().save(tmp_path / "p.safetensors")
    tensors = load_file(str(path))
    assert set(tensors) == {f"network.{k}" for k in seeded_network().state_dict()}
    from safetensors import safe_open

    with safe_open(str(path), "pt") as handle:
        raw = handle.metadata()
    assert list(raw) == ["camdegrade"]
    metadata = json.loads(raw["camdegrade"])
    assert metadata["format"] == "camdegrade-profile" and metadata["format_version"] == FORMAT_VERSION
    assert metadata["network"] == {"arch": "DomainShiftNet", "config": {"width": 64}}
    assert metadata["effects"] == []


def test_save_is_atomic_and_keeps_the_old_file_on_failure(tmp_path, monkeypatch):
    path = deterministic_profile().save(tmp_path / "p.safetensors")
    before = path.read_bytes()

    def explode(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr("camdegrade.profile.save_file", explode)
    with pytest.raises(OSError, match="disk full"):
        stochastic_profile().save(path)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.safetensors"]


def test_same_profile_saves_identical_bytes(tmp_path):
    first = deterministic_profile().save(tmp_path / "a.safetensors").read_bytes()
    second = deterministic_profile().save(tmp_path / "b.safetensors").read_bytes()
    assert first == second


def test_save_refuses_other_suffixes(tmp_path):
    with pytest.raises(ValueError, match=r"must end in '\.safetensors'"):
        deterministic_profile().save(tmp_path / "p.pth")


def test_pickled_checkpoint_is_refused_without_unpickling(tmp_path):
    path = tmp_path / "model.pth"
    torch.save(seeded_network().state_dict(), path)
    with pytest.raises(ProfileError, match=r"pickled PyTorch checkpoint.*never unpickles"):
        load_profile(path)
    raw = tmp_path / "model.safetensors"
    raw.write_bytes(pickle.dumps({"a": 1}))
    with pytest.raises(ProfileError, match="pickled"):
        load_profile(raw)


@pytest.mark.parametrize("keep", [0.5, 0.99])
def test_truncated_file(tmp_path, keep):
    path = deterministic_profile().save(tmp_path / "p.safetensors")
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])
    with pytest.raises(ProfileError, match=r"corrupt or truncated|not a safetensors file"):
        load_profile(path)


def test_random_bytes(tmp_path):
    path = tmp_path / "p.safetensors"
    path.write_bytes(os.urandom(1000))
    with pytest.raises(ProfileError, match="not a safetensors file"):
        load_profile(path)


def _rewrite_metadata(tmp_path, **changes):
    source = stochastic_profile()
    tensors = {k: v.contiguous() for k, v in source.state_dict().items()}
    metadata = serialize_metadata({**source.metadata(), **changes})
    path = tmp_path / "edited.safetensors"
    save_file(tensors, str(path), metadata=metadata)
    return path


def test_newer_format_version_is_refused(tmp_path):
    path = _rewrite_metadata(tmp_path, format_version=FORMAT_VERSION + 1)
    with pytest.raises(ProfileError, match=rf"format version {FORMAT_VERSION + 1}, newer.*upgrade camdegrade"):
        load_profile(path)


def test_foreign_safetensors_is_refused(tmp_path):
    path = tmp_path / "foreign.safetensors"
    save_file({"weight": torch.zeros(2)}, str(path))
    with pytest.raises(ProfileError, match="not a camdegrade profile"):
        load_profile(path)


def test_unknown_effect_is_named(tmp_path):
    path = _rewrite_metadata(tmp_path, effects=[{"name": "lens_flare", "config": {}}])
    with pytest.raises(ProfileError, match="uses effect 'lens_flare'"):
        load_profile(path)


def test_missing_and_unexpected_tensors_are_listed(tmp_path):
    source = stochastic_profile()
    tensors = {k: v.contiguous() for k, v in source.state_dict().items() if k != "network.decode2.bias"}
    tensors["effects.0.extra"] = torch.zeros(1)
    path = tmp_path / "broken.safetensors"
    save_file(tensors, str(path), metadata=serialize_metadata(source.metadata()))
    with pytest.raises(
        ProfileError,
        match=r"missing tensors: network\.decode2\.bias.*unexpected tensors: "
        r"effects\.0\.extra",
    ):
        load_profile(path)


def test_wrong_shape_is_listed(tmp_path):
    source = stochastic_profile()
    tensors = {k: v.contiguous() for k, v in source.state_dict().items()}
    tensors["network.decode2.bias"] = torch.zeros(4)
    path = tmp_path / "shape.safetensors"
    save_file(tensors, str(path), metadata=serialize_metadata(source.metadata()))
    with pytest.raises(ProfileError, match=r"wrong shapes: network\.decode2\.bias \(4,\) \(expected \(3,\)\)"):
        load_profile(path)


def test_unknown_name_lists_the_built_ins():
    with pytest.raises(UnknownProfileError) as info:
        load_profile("no-such-camera")
    assert "no-such-camera" in str(info.value)
    for name in list_profiles():
        assert name in str(info.value)


def test_built_in_profiles_load_by_name():
    names = list_profiles()
    assert "city100-iphonex" in names
    for name in names:
        profile = load_profile(name)
        assert profile.name == name and profile.network is not None
        assert profile.quality, f"built-in {name} must record its held-out quality"


def test_built_in_city100_beats_identity_on_its_held_out_scenes():
    quality = load_profile("city100-iphonex").quality
    assert quality["held_out_pairs"] == 16
    assert quality["network_psnr_db"] > quality["identity_psnr_db"]


def test_load_to_device():
    profile = load_profile("city100-iphonex", device="cpu")
    assert next(profile.parameters()).device == torch.device("cpu")


def test_with_effects_inserts_in_physical_order():
    class Optic(AdditiveTestNoise):
        name = "test_additive_noise"
        stage = "optics"

    profile = stochastic_profile().with_effects(Optic(0.01), AdditiveTestNoise(0.02))
    assert [e.stage for e in profile.effects] == ["optics", "sensor", "sensor"]
    assert float(profile.effects[2].std) == pytest.approx(0.02)


def test_constructor_checks_types():
    with pytest.raises(TypeError, match="network must be a DomainShiftNet, a LocalAffineNet or None, got Linear"):
        CameraProfile(torch.nn.Linear(2, 2))
    with pytest.raises(TypeError, match=r"effects\[0\] must be a camdegrade Effect"):
        CameraProfile(None, [torch.nn.Identity()])


def test_describe_lists_the_chain():
    text = stochastic_profile().describe()
    assert "test_additive_noise [sensor]" in text and "DomainShiftNet" in text


def test_saved_profile_has_ordinary_permissions(tmp_path):
    path = deterministic_profile().save(tmp_path / "p.safetensors")
    umask = os.umask(0)
    os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~umask


def test_header_lengths_that_start_like_a_pickle_still_load(tmp_path):
    """A safetensors header of 640 bytes begins with b'\\x80\\x02', a pickle's opening bytes."""
    for extra in range(0, 400, 7):
        profile = deterministic_profile()
        profile.description = "x" * extra
        path = profile.save(tmp_path / "p.safetensors")
        assert load_profile(path).description == "x" * extra


@pytest.mark.parametrize(
    "change, message",
    [
        ({"network": {"arch": "OtherNet", "config": {}}}, "must be null or"),
        ({"network": "oops"}, "must be null or"),
        ({"network": {"arch": "DomainShiftNet", "config": {"depth": 3}}}, "invalid metadata"),
        ({"effects": ["noise"]}, "not {'name', 'config'}"),
        ({"effects": [{"name": "test_additive_noise", "config": {"sigma": 1}}]}, "invalid metadata"),
    ],
)
def test_invalid_metadata_is_a_profile_error(tmp_path, change, message):
    with pytest.raises(ProfileError, match=re.escape(message)):
        load_profile(_rewrite_metadata(tmp_path, **change))
