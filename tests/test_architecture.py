"""The house rules of docs/architecture.md, checked: effect facts live on the effect classes, one seed scheme,
old import paths deprecated with a warning, and the layers import only downward."""

from __future__ import annotations

import ast
import importlib
import subprocess
import sys
from pathlib import Path

import pytest
import torch

import camdegrade
from camdegrade._seeds import derive_seed, derived_generator
from camdegrade.effects import EFFECTS, Effect
from camdegrade.effects.base import STAGES
from camdegrade.measures import FAMILIES
from effects_images import photo_batch

PACKAGE = Path(camdegrade.__file__).parent
#: The names the test-only effects register (tests/profiles_for_tests.py) are not part of the package.
REGISTERED = sorted(name for name, cls in EFFECTS.items() if cls.__module__.startswith("camdegrade."))


@pytest.mark.parametrize("name", REGISTERED)
def test_every_effect_states_its_facts(name: str) -> None:
    cls = EFFECTS[name]
    assert cls.stage in STAGES
    assert set(cls.explains) <= set(FAMILIES) and cls.explains, "every effect leaves some signature"
    assert cls.fit_budget is None or (isinstance(cls.fit_budget, int) and cls.fit_budget > 0)
    assert isinstance(cls.position_dependent, bool)
    assert isinstance(cls.fit_options(list(photo_batch())), dict)


@pytest.mark.parametrize("name", REGISTERED)
def test_strength_scales_between_neutral_and_fitted(name: str) -> None:
    """Strength 0 is the neutral effect (its values, or images left unchanged: a blur of zero width keeps its
    angle), strength 1 is the effect as it is, and strength grows with ``scaled`` (what the diagnosis's strength
    refinement and 'too strong' texts rely on)."""
    from test_effects import strong

    effect = strong(name)
    centre = effect.without_randomness() or effect  # per-sample jitter is not strength
    image = photo_batch()
    zero = centre.scaled(0.0)
    neutral = type(effect).neutral().state_dict()
    params = zero.make_params(image.shape, torch.Generator().manual_seed(0))
    neutral_values = all(
        torch.allclose(v, neutral[k].to(v.dtype)) for k, v in zero.state_dict().items() if k in neutral
    )
    assert neutral_values or (zero(image, params) - image).abs().max() <= 1 / 255, name
    for key, value in effect.scaled(1.0).state_dict().items():
        assert torch.allclose(value, effect.state_dict()[key]), (name, key)
    assert type(effect.scaled(0.5)) is type(effect)
    assert centre.scaled(0.5).magnitude() < centre.magnitude() < centre.scaled(1.5).magnitude()


@pytest.mark.parametrize("name", REGISTERED)
def test_deterministic_centre_draws_nothing(name: str) -> None:
    from test_effects import strong

    centre = strong(name).without_randomness()
    if centre is None:  # pure noise: the conditional mean leaves it out
        assert strong(name).make_params((1, 3, 8, 8), torch.Generator())
        return
    assert isinstance(centre, Effect)
    assert centre.make_params((2, 3, 8, 8), torch.Generator().manual_seed(0)) == {}


def _compared_effect_names(tree: ast.AST) -> list[str]:
    """String literals naming a registered effect that appear in a comparison (``==``, ``!=``, ``in``)."""
    found = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Compare):
            continue
        for operand in [node.left, *node.comparators]:
            literals = operand.elts if isinstance(operand, (ast.Set, ast.Tuple, ast.List)) else [operand]
            found += [
                item.value
                for item in literals
                if isinstance(item, ast.Constant) and isinstance(item.value, str) and item.value in EFFECTS
            ]
    return found


def test_no_module_outside_effects_compares_an_effect_name() -> None:
    offenders = {}
    for path in PACKAGE.rglob("*.py"):
        if "effects" in path.relative_to(PACKAGE).parts:
            continue
        names = _compared_effect_names(ast.parse(path.read_text()))
        if names:
            offenders[str(path.relative_to(PACKAGE))] = names
    assert not offenders


def test_the_name_check_can_fail() -> None:
    assert _compared_effect_names(ast.parse("if effect.name == 'noise': pass")) == ["noise"]
    assert _compared_effect_names(ast.parse("x = name in {'blur', 'jpeg'}")) == ["blur", "jpeg"]


def test_where_suspects_come_from_the_effect_classes() -> None:
    from camdegrade.diagnose.where import suspects

    for axis in FAMILIES:
        expected = [name for name in EFFECTS if axis in EFFECTS[name].explains]
        assert suspects(axis) == (", ".join(expected) or "the network")
    assert "blur" in suspects("frequency") and "noise" not in suspects("frequency")


def test_seed_scheme_is_a_fixed_formula() -> None:
    assert derive_seed(0) == 0xE220A8397B1DCDAF  # SplitMix64's finaliser of 0 (the data streams' old keys)
    assert derive_seed(3, "simulate", "a.png") == derive_seed(3, "simulate", "a.png")
    assert len({derive_seed(3, stream, 0) for stream in ("simulate", "held-out", "held-out.null", 1, 2)}) == 5
    first = torch.randn(4, generator=derived_generator(1, "x"))
    assert torch.equal(first, torch.randn(4, generator=derived_generator(1, "x")))


def test_seed_scheme_is_the_same_in_another_process() -> None:
    code = "from camdegrade._seeds import derive_seed; print(derive_seed(7, 'dataloader-worker', 3))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert int(out) == derive_seed(7, "dataloader-worker", 3)


@pytest.mark.parametrize(
    ("old", "new", "name"),
    [
        ("camdegrade.pairs", "camdegrade.fitting.pairs", "discover_pairs"),
        ("camdegrade.align", "camdegrade.fitting.align", "align_pair"),
        ("camdegrade.training", "camdegrade.fitting.training", "FitConfig"),
        ("camdegrade.checkpoint", "camdegrade.fitting.checkpoint", "load_checkpoint"),
        ("camdegrade.fit", "camdegrade.fitting.fit", "fit_profile"),
    ],
)
def test_old_module_paths_still_work_with_a_deprecation_warning(old: str, new: str, name: str) -> None:
    module = importlib.import_module(old)
    with pytest.warns(DeprecationWarning, match=f"import {name} from {new}"):
        value = getattr(module, name)
    assert value is getattr(importlib.import_module(new), name)
    with pytest.raises(AttributeError):
        module.no_such_name  # noqa: B018


def test_the_mixing_policy_pair_is_a_deprecated_name() -> None:
    from camdegrade.data import Pair, PairedViews, resolve_policy

    with pytest.warns(DeprecationWarning, match="PairedViews"):
        policy = Pair()
    assert isinstance(policy, PairedViews) and policy.decide(0, 0, 0, 0) == (False, True)
    assert type(resolve_policy("pair")) is PairedViews


#: room → rooms it must not import (its place in docs/architecture.md's table).
FORBIDDEN = {
    "functional": ("effects", "profile", "engine", "transform", "data", "fitting", "diagnose", "network", "sim"),
    "effects": ("profile", "engine", "transform", "data", "fitting", "diagnose", "network", "sim", "io"),
    "profile": ("engine", "transform", "data", "fitting", "diagnose", "sim"),
    "engine": ("transform", "data", "fitting", "diagnose", "sim"),
    "data": ("fitting", "diagnose", "sim"),
    "fitting": ("diagnose", "transform", "data"),
    "measures": ("profile", "engine", "transform", "data", "fitting", "diagnose", "sim"),
    "synthetic": ("effects", "profile", "engine", "transform", "data", "fitting", "diagnose", "network", "inference"),
    "inference": ("effects", "profile", "engine", "transform", "data", "fitting", "diagnose", "sim", "io"),
}


def _imported_rooms(path: Path) -> set[str]:
    rooms = set()
    for node in ast.walk(ast.parse(path.read_text())):
        names = [node.module] if isinstance(node, ast.ImportFrom) and node.module else []
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        rooms |= {name.split(".")[1] for name in names if name.startswith("camdegrade.") and name.count(".") >= 1}
    return rooms


@pytest.mark.parametrize("room", sorted(FORBIDDEN))
def test_layers_import_only_downward(room: str) -> None:
    paths = [PACKAGE / f"{room}.py"] if (PACKAGE / f"{room}.py").exists() else list((PACKAGE / room).rglob("*.py"))
    assert paths
    for path in paths:
        wrong = _imported_rooms(path) & set(FORBIDDEN[room])
        assert not wrong, (str(path.relative_to(PACKAGE)), wrong)


def test_the_policy_module_imports_only_leaf_helpers() -> None:
    """Mixing policies are small and stateless: no transform, no torchvision, no PIL behind them."""
    for name in ("policies.py", "_keys.py"):
        tree = ast.parse((PACKAGE / "data" / name).read_text())
        modules = {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)}
        modules |= {alias.name for node in ast.walk(tree) if isinstance(node, ast.Import) for alias in node.names}
        inside = {m for m in modules if m and m.startswith("camdegrade")}
        assert inside <= {"camdegrade._checks", "camdegrade._seeds", "camdegrade.data._keys"}, (name, inside)
        assert not {m for m in modules if m and m.split(".")[0] in ("torchvision", "PIL")}
