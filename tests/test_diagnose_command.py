"""The refit command a diagnosis suggests is safe to paste: built from the path the user gave, every argument quoted."""

import shlex
from pathlib import Path

import pytest
import torch

from camdegrade.diagnose.attribution.changes import Change
from camdegrade.diagnose.verdict import command_reference, finding, refit_command
from camdegrade.pairs.pair import PairReport
from camdegrade.profile import CameraProfile

HOSTILE = [
    "cam; touch PWNED #",
    "my camera.safetensors",
    'it\'s "quoted".safetensors',
    "$(touch PWNED).safetensors",
    "`touch PWNED`",
    "two\nlines.safetensors",
    "-rf",
    "",
]


def _intended(pairs: str, profile: str) -> list[str]:
    return [
        "camdegrade", "fit", pairs, "-o", "REFIT.safetensors", "--init-from", profile,
        "--epochs", "20", "--lr", "0.001",
    ]  # fmt: skip


@pytest.mark.parametrize("hostile", HOSTILE)
def test_the_suggested_command_splits_into_exactly_the_intended_arguments(hostile):
    pairs = f"/data/{hostile}/pairs"
    profile = f"/profiles/{hostile}" if hostile else "city100-iphonex"
    assert shlex.split(refit_command(profile, pairs)) == _intended(pairs, profile)


@pytest.mark.parametrize("hostile", [name for name in HOSTILE if name])
def test_a_hostile_name_as_the_whole_argument_stays_one_argument(hostile):
    expected_profile = f"./{hostile}" if hostile.startswith("-") else hostile
    assert shlex.split(refit_command(hostile, hostile)) == _intended(expected_profile, expected_profile)


def test_the_command_names_the_path_given_not_the_profile_s_stored_name(tmp_path):
    path = tmp_path / "my cam; rm -rf x.safetensors"
    CameraProfile(None, name="cam; touch PWNED #").save(path)
    assert command_reference(path, "PROFILE") == str(path)
    assert command_reference(str(path), "PROFILE") == str(path)
    assert command_reference(CameraProfile(None, name="cam; touch PWNED #"), "PROFILE") == "PROFILE"


def test_pairs_are_named_by_the_folder_they_were_found_in_or_a_placeholder(tmp_path):
    assert command_reference(PairReport(pairs=[], source=tmp_path), "PAIRS") == str(tmp_path)
    assert command_reference(PairReport(pairs=[]), "PAIRS") == "PAIRS"
    assert command_reference([(torch.zeros(3, 8, 8), torch.zeros(3, 8, 8))], "PAIRS") == "PAIRS"


def test_a_network_finding_carries_the_quoted_command():
    change = Change(kind="network", name="network", profile=None, effect=None, gap_after=0.0)
    command = refit_command(str(Path("/tmp/cam; touch PWNED #.safetensors")), "/tmp/new pairs")
    _, fix = finding(change, command)
    inside = fix[fix.index("(") + 1 : fix.rindex(")")]
    assert shlex.split(inside) == _intended("/tmp/new pairs", "/tmp/cam; touch PWNED #.safetensors")
