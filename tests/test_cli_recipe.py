"""Issue 22: the CLI built from the library. Every recipe field is a ``fit`` option (and a ``distill`` one, or is
listed as not offered, with the reason), with its help and default from the one recipe table; ``diagnose``'s
options follow the keywords of ``diagnose``; a ``fit`` discovers its pairs once and hands them down as one value."""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import sys
from collections import Counter
from pathlib import Path

import pytest

import camdegrade
import camdegrade.fitting.network.training as training_module
import camdegrade.pairs.discovery as pairs_module
from camdegrade._support.recipes import FAST, FIELDS, PAPER, TRAINING_FIELDS, recipe_default
from camdegrade.cli import diagnose as diagnose_command
from camdegrade.cli import distill as distill_command
from camdegrade.cli import main, main_parser
from camdegrade.fitting import DEFAULT_EFFECTS, FitConfig, PairSet, fit_profile
from camdegrade.fitting.steps import STEPS
from test_fit import QUICK, make_pairs_folder


def _options(command: str) -> dict[str, argparse.Action]:
    parser = main_parser("camdegrade")
    subparsers = next(action for action in parser._actions if isinstance(action, argparse._SubParsersAction))
    return {option: action for action in subparsers.choices[command]._actions for option in action.option_strings}


def test_the_recipe_table_has_one_entry_per_fit_config_field_or_step_option() -> None:
    plain = [field.name for field in FIELDS if field.plain]
    assert [field.name for field in dataclasses.fields(FitConfig)] == [*plain, "steps"]
    assert list(FAST) == list(PAPER) == [*plain, "steps"]
    assert FitConfig() == FitConfig.recipe("fast") and FitConfig().option("effects") == DEFAULT_EFFECTS
    assert set(TRAINING_FIELDS) < set(FAST)
    for field in FIELDS:  # every step field names a registered step (and an option it has)
        if field.step:
            step, option = field.step.split(".")
            assert option in {item.name for item in dataclasses.fields(STEPS[step])}, field.name
        assert set(field.toggles) <= set(STEPS), field.name


def test_the_cli_options_of_the_switches_map_onto_the_steps() -> None:
    """``--effects``, ``--texture`` and ``--sensor-scale`` set the options of the recipe's steps (or which run)."""
    fast = FitConfig.recipe("fast")
    names = ["resolution", "effects", "resampler", "texture", "denoise", "response", "mosaic", "jitter"]
    assert [step.name for step in fast.steps] == names
    none = fast.replace(texture="none", effects=(), sensor_scale=0.5)
    assert [step.name for step in none.steps] == ["resolution", "effects", "resampler", "mosaic", "jitter"]
    assert [step.name for step in fast.replace(jitter="none").steps] == names[:-1]
    assert none.option("effects") == () and none.option("sensor_scale") == 0.5 and none.option("texture") == "none"
    assert none.left_out() == {
        **{name: "texture='none'" for name in ("texture", "denoise", "response")},
        "learned_texture": "learned_texture='none'",  # no recipe's default (issue 43)
    }
    assert none.replace(texture="match") == fast.replace(effects=(), sensor_scale=0.5)  # back in their places
    paper = FitConfig.recipe("paper")
    assert [step.name for step in paper.steps] == ["resolution", "effects"] and paper.option("sensor_scale") == 1.0
    with pytest.raises(ValueError, match=r"texture must be one of \('match', 'none'\), got texture='sharp'"):
        fast.replace(texture="sharp")
    with pytest.raises(ValueError, match=r"steps: no fit step is named 'texure'"):
        fast.replace(steps=("resolution", "texure"))
    with pytest.raises(ValueError, match=r"steps: \['resolution'\] come before the network"):
        fast.replace(steps=("effects", "resolution"))


@pytest.mark.parametrize("command, not_offered", [("fit", {}), ("distill", distill_command.NOT_OFFERED)])
def test_every_recipe_field_is_an_option_with_the_tables_help(command: str, not_offered: dict[str, str]) -> None:
    options = _options(command)
    for field in FIELDS:
        if field.name in not_offered:
            assert field.option not in options and not_offered[field.name]
            continue
        action = options[field.option]
        assert action.dest == field.name and action.default is None  # left out: the recipe's value
        assert action.help.startswith(field.help), field.name
        if command == "fit":
            assert action.help.endswith(f"({recipe_default(field.name)})")
        assert list(action.choices or []) == list(field.choices), field.name


def test_fit_options_build_the_recipe_they_name(tmp_path) -> None:
    parser = main_parser("camdegrade")
    argv = ["fit", "pairs", "-o", "x.safetensors", "--recipe", "paper", "--lr", "0.02", "--effects", "noise"]
    from camdegrade.cli._recipe import recipe_changes

    args = parser.parse_args([*argv, "--val-fraction", "0", "--precision", "float32"])
    recipe = FitConfig.recipe(args.recipe, **recipe_changes(args))
    assert recipe == FitConfig.recipe("paper").replace(
        lr=0.02, effects=("noise",), val_fraction=0.0, precision="float32"
    )
    assert parser.parse_args([*argv[:4], "--no-effects"]).effects == []


def test_every_pair_loading_option_is_a_fit_option() -> None:
    options = _options("fit")
    keywords = set(inspect.signature(PairSet.load).parameters) - {"source", "log"}
    assert {"--" + keyword.replace("_", "-") for keyword in keywords} <= set(options)


def test_diagnose_offers_every_keyword_of_diagnose_or_says_why_not() -> None:
    from camdegrade.diagnose import diagnose

    dests = {action.dest for action in _options("diagnose").values()}
    keywords = set(inspect.signature(diagnose).parameters) - {"profile", "pairs"}
    offered = keywords - set(diagnose_command.NOT_OFFERED)
    assert offered <= dests, sorted(offered - dests)
    assert set(diagnose_command.NOT_OFFERED) <= keywords  # no stale entry


def test_fit_profile_takes_a_pair_set_and_a_recipe_in_at_most_12_parameters() -> None:
    parameters = inspect.signature(fit_profile).parameters
    assert len(parameters) <= 12 and list(parameters)[:2] == ["pairs", "recipe"]


def test_a_fit_discovers_its_pairs_once(tmp_path, monkeypatch) -> None:
    collect, calls = pairs_module._collect, []

    def counted(*args, **kwargs):
        calls.append(args[0])
        return collect(*args, **kwargs)

    monkeypatch.setattr(pairs_module, "_collect", counted)
    folder = make_pairs_folder(tmp_path / "pairs", count=4)
    assert main(["fit", str(folder), "-o", str(tmp_path / "cam.safetensors"), *QUICK, "--epochs", "1"]) == 0
    assert len(calls) == 1


class _FirstStep(Exception):
    """Raised where training would take its first step: the walk being measured ends there."""


def _carries_pairs(value: object, folder: Path) -> bool:
    """Whether a call's argument is the pairs in one of their forms: the folder, its report, a pair set, pairs."""
    if type(value).__name__ in ("PairReport", "PairSet", "Pair"):
        return True
    if isinstance(value, (str, Path)):
        return str(value) == str(folder)
    return isinstance(value, (list, tuple)) and bool(value) and type(value[0]).__name__ in ("Pair", "PairSet")


def _rooms_the_pairs_walk_through(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The modules ("rooms") of the package that receive the pairs as an argument, from ``camdegrade fit PAIRS`` to
    the first training step, a new entry each time the walk comes back to a room it had left (leaf helpers such as
    ``_text`` are part of the room that calls them)."""
    folder = make_pairs_folder(tmp_path / "pairs", count=4)

    def first_step(*args, **kwargs):
        raise _FirstStep

    monkeypatch.setattr(training_module, "_train_one_epoch", first_step)
    package = str(Path(camdegrade.__file__).parent)
    rooms: list[str] = []

    def follow(frame, event, arg) -> None:
        if event != "call" or not frame.f_code.co_filename.startswith(package):
            return
        if any(_carries_pairs(value, folder) for value in frame.f_locals.values()):
            room = str(Path(frame.f_code.co_filename).relative_to(package))
            if room.startswith("_"):
                return  # a leaf helper (_text, _files, ...) called from the room the walk is in
            if not rooms or rooms[-1] != room:
                rooms.append(room)

    sys.setprofile(follow)
    try:
        with pytest.raises(_FirstStep):
            main(["fit", str(folder), "-o", str(tmp_path / "cam.safetensors"), *QUICK, "--epochs", "1"])
    finally:
        sys.setprofile(None)
    return rooms


def test_the_pairs_enter_no_room_more_than_twice_on_their_way_to_training(tmp_path, monkeypatch) -> None:
    """Issue 22: followed as a value from the CLI's fit to the first training step (before: pairs.py and
    pairset.py three times each, the files discovered twice)."""
    rooms = _rooms_the_pairs_walk_through(tmp_path, monkeypatch)
    assert rooms[0] == "pairs/discovery.py" and "fitting/fit.py" in rooms, rooms  # the walk was seen
    assert max(Counter(rooms).values()) <= 2, rooms


def test_a_recipe_changes_by_replace_and_refuses_unknown_fields() -> None:
    fast = FitConfig.recipe("fast")
    changed = fast.replace(epochs=3, lr=None)  # None keeps the recipe's value
    assert changed.epochs == 3 and changed.lr == fast.lr and fast.epochs == FAST["epochs"]
    with pytest.raises(TypeError, match=r"FitConfig has no field\(s\) \['epoch'\]"):
        fast.replace(epoch=3)
    with pytest.raises(ValueError, match=r"val_fraction must be in \[0, 1\), got val_fraction=1"):
        fast.replace(val_fraction=1)
    assert fast.training_dict() == {name: getattr(fast, name) for name in TRAINING_FIELDS}
