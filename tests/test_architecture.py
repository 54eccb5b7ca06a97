"""The house rules of docs/architecture.md, checked: effect facts live on the effect classes, one seed scheme, the
layers import only downward, no import cycles, no shim modules, no function longer than 60 lines, no file longer than
400 and no folder of more than 10 modules unless it says why; a fit is a loop of steps."""

from __future__ import annotations

import ast
import subprocess
import sys
import textwrap
from collections import Counter
from pathlib import Path

import pytest
import torch

import camdegrade
from camdegrade._support.seeds import derive_seed, derived_generator
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
        expected = [name for name in EFFECTS if axis in EFFECTS[name].explains and EFFECTS[name].candidate]
        assert suspects(axis) == (", ".join(expected) or "the network")
    named = suspects("frequency").split(", ")
    assert "blur" in named and "noise" not in named and "frequency_response" not in named


def test_seed_scheme_is_a_fixed_formula() -> None:
    assert derive_seed(0) == 0xE220A8397B1DCDAF  # SplitMix64's finaliser of 0 (the data streams' old keys)
    assert derive_seed(3, "simulate", "a.png") == derive_seed(3, "simulate", "a.png")
    assert len({derive_seed(3, stream, 0) for stream in ("simulate", "held-out", "held-out.null", 1, 2)}) == 5
    first = torch.randn(4, generator=derived_generator(1, "x"))
    assert torch.equal(first, torch.randn(4, generator=derived_generator(1, "x")))


@pytest.mark.slow
def test_seed_scheme_is_the_same_in_another_process() -> None:
    code = "from camdegrade._support.seeds import derive_seed; print(derive_seed(7, 'dataloader-worker', 3))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert int(out) == derive_seed(7, "dataloader-worker", 3)


#: room → rooms it must not import (its place in docs/architecture.md's table).
FORBIDDEN = {
    "functional": ("effects", "profile", "engine", "transform", "data", "fitting", "diagnose", "network", "sim"),
    "effects": ("profile", "engine", "transform", "data", "fitting", "diagnose", "network", "sim", "io"),
    "profile": ("engine", "transform", "data", "fitting", "diagnose", "sim"),
    "engine": ("transform", "data", "fitting", "diagnose", "sim"),
    "data": ("fitting", "diagnose", "sim"),
    "fitting": ("diagnose", "transform", "data"),
    "measures": ("profile", "engine", "transform", "data", "fitting", "diagnose", "sim"),
    "synthetic": ("effects", "profile", "engine", "transform", "data", "fitting", "diagnose", "network"),
    "network": ("effects", "profile", "engine", "transform", "data", "fitting", "diagnose", "sim", "io"),
    "pairs": ("effects", "profile", "engine", "transform", "data", "fitting", "diagnose", "network", "measures", "sim"),
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
        assert inside <= {"camdegrade._support.checks", "camdegrade._support.seeds", "camdegrade.data._keys"}, (
            name,
            inside,
        )
        assert not {m for m in modules if m and m.split(".")[0] in ("torchvision", "PIL")}


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {_module_name(path): path for path in PACKAGE.rglob("*.py")}


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _runtime_imports(source: str, module: str, modules: set[str], is_package: bool = False) -> set[str]:
    """The camdegrade modules ``module`` imports when it runs: at its top and inside its functions alike (a cycle
    through a function-level import is still two modules that need each other), but not under ``if TYPE_CHECKING:``.
    ``from package import name`` counts as importing ``package.name`` when that is a module, else ``package``."""
    package = module if is_package else module.rpartition(".")[0]
    found: set[str] = set()

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            for child in node.orelse:
                visit(child)
            return
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: from the package, up level - 1 packages
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, *([node.module] if node.module else [])])
            found.update(f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules else base for alias in node.names)
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(ast.parse(source))
    resolved = set()
    for name in found:
        while name and name not in modules:  # `import camdegrade.x.y` of a name inside a module: the module
            name = name.rpartition(".")[0]
        if name and name != module:
            resolved.add(name)
    return resolved


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The groups of modules that import each other, directly or round a loop (strongly connected components of
    more than one module, Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    groups: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        for target in sorted(graph.get(node, ())):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            group = []
            while (member := stack.pop()) != node:
                group.append(member)
            if group:
                groups.append(sorted([node, *group]))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return groups


def test_no_import_cycles() -> None:
    graph = {
        name: _runtime_imports(path.read_text(), name, set(MODULES), path.name == "__init__.py")
        for name, path in MODULES.items()
    }
    assert sum(len(targets) for targets in graph.values()) > 100  # the graph was read, not empty
    assert _cycles(graph) == []


def test_the_cycle_check_can_fail() -> None:
    modules = {"camdegrade.a", "camdegrade.b", "camdegrade.c", "camdegrade.pkg", "camdegrade.pkg.x"}
    a = "from camdegrade.b import f\nif TYPE_CHECKING:\n    from camdegrade.c import C\n"
    b = "def g():\n    from camdegrade.a import h\n"
    pkg = "from camdegrade.pkg import x\nfrom . import x as y\nimport camdegrade.a.h\n"
    assert _runtime_imports(a, "camdegrade.a", modules) == {"camdegrade.b"}
    assert _runtime_imports(b, "camdegrade.b", modules) == {"camdegrade.a"}
    assert _runtime_imports(pkg, "camdegrade.pkg", modules, is_package=True) == {"camdegrade.pkg.x", "camdegrade.a"}
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": set(), "e": {"d"}}
    assert _cycles(graph) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


#: Modules of the never-released 0.1.0 layout (moved into camdegrade.fitting) and the helper that forwarded them.
#: (``camdegrade.pairs`` is a package again: the pairs' own wing, not a module forwarding names.)
REMOVED_SHIMS = ("fit", "training", "align", "checkpoint", "_deprecated")


@pytest.mark.parametrize("name", REMOVED_SHIMS)
def test_no_shim_module_at_the_top_level(name: str) -> None:
    assert not (PACKAGE / f"{name}.py").exists()
    with pytest.raises(AttributeError):
        getattr(camdegrade, name)


def test_nothing_in_the_package_is_deprecated() -> None:
    """Old names are deleted, not kept behind a warning: nothing was released under them."""
    warned = [
        _module_name(path)
        for path in MODULES.values()
        if any(isinstance(n, ast.Name) and n.id == "DeprecationWarning" for n in ast.walk(ast.parse(path.read_text())))
    ]
    assert warned == []


#: Functions allowed more than MAX_FUNCTION_LINES lines, each with the reason.
LONG_FUNCTIONS: dict[str, str] = {}
MAX_FUNCTION_LINES = 60
MAX_FILE_LINES = 400
MAX_FOLDER_MODULES = 10
#: Modules (path in the package) allowed more than MAX_FILE_LINES lines and folders ("path/", "./" the package
#: itself) allowed more than MAX_FOLDER_MODULES modules, each with the reason: what is left for a later split.
TOO_BIG: dict[str, str] = {}


def _function_lengths(source: str, module: str) -> dict[str, int]:
    """Every function's length in lines, from its first statement after the docstring to its last line (nested
    functions count in their parent and on their own), keyed ``module.Qualified.name``."""
    lengths = {}

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            name = (
                f"{prefix}.{child.name}"
                if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef))
                else prefix
            )
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                body = child.body
                if len(body) > 1 and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                    body = body[1:]  # the docstring
                lengths[name] = child.end_lineno - body[0].lineno + 1
            visit(child, name)

    visit(ast.parse(source), module)
    return lengths


def _all_function_lengths() -> dict[str, int]:
    lengths = {}
    for name, path in MODULES.items():
        lengths |= _function_lengths(path.read_text(), name.removeprefix("camdegrade."))
    return lengths


def _over_without_reason(sizes: dict[str, int], limit: int, allowed: dict[str, str]) -> tuple[list, list]:
    """``(what is over limit and not allowed, what is allowed but no longer over it)``."""
    over = {name for name, size in sizes.items() if size > limit}
    return sorted(over - set(allowed)), sorted(name for name in allowed if sizes.get(name, 0) <= limit)


def test_no_function_is_longer_than_60_lines_without_a_reason() -> None:
    lengths = _all_function_lengths()
    too_long, stale = _over_without_reason(lengths, MAX_FUNCTION_LINES, LONG_FUNCTIONS)
    assert not too_long, sorted((lengths[name], name) for name in too_long)
    assert not stale, f"allowed but gone or short now, remove them from LONG_FUNCTIONS: {stale}"
    assert len(lengths) > 500


def test_no_file_is_longer_than_400_lines_without_a_reason() -> None:
    lines = {str(path.relative_to(PACKAGE)): len(path.read_text().splitlines()) for path in MODULES.values()}
    files = {name: why for name, why in TOO_BIG.items() if not name.endswith("/")}
    too_long, stale = _over_without_reason(lines, MAX_FILE_LINES, files)
    assert not too_long and not stale, (too_long, f"allowed but short now, remove from TOO_BIG: {stale}")


def test_no_folder_holds_more_than_10_modules_without_a_reason() -> None:
    folders = Counter(f"{path.parent.relative_to(PACKAGE)}/" for path in MODULES.values())
    allowed = {name: why for name, why in TOO_BIG.items() if name.endswith("/")}
    crowded, stale = _over_without_reason(folders, MAX_FOLDER_MODULES, allowed)
    assert not crowded and not stale, (crowded, f"allowed but small now, remove from TOO_BIG: {stale}")
    assert folders["fitting/steps/"] and folders["pairs/"]  # the folders were read


def test_the_size_checks_can_fail() -> None:
    assert _over_without_reason({"a": 5, "b": 3, "c": 9}, 4, {"c": "why", "d": "gone"}) == (["a"], ["d"])


def test_a_fit_is_a_loop_of_steps() -> None:
    """``fit_profile`` is load → split → the recipe's steps (the network among them) → record, in at most 40 lines
    and with no record written by hand; the unpaired fit runs the same loop over its steps, and its state is one
    small class (issue 45)."""
    from camdegrade.fitting import fit, steps
    from camdegrade.fitting.unpaired import UNPAIRED_STEPS, bench

    lengths = _all_function_lengths()
    assert lengths["fitting.fit.fit_profile"] <= 40
    assert lengths["fitting.unpaired.fit.fit_unpaired"] <= 40
    for module in (fit, PACKAGE / "fitting" / "unpaired" / "fit.py"):
        source = module.read_text() if isinstance(module, Path) else Path(module.__file__).read_text()
        assert "run_steps(" in source and "_note" not in source
    assert all(isinstance(step, steps.FitStep) for _, step in UNPAIRED_STEPS)
    assert not hasattr(bench, "_UnpairedFit")
    state = next(
        n for n in ast.walk(ast.parse(Path(bench.__file__).read_text())) if getattr(n, "name", "") == "UnpairedFit"
    )
    assert state.end_lineno - state.lineno + 1 <= 120


def test_the_function_length_check_can_fail() -> None:
    source = textwrap.dedent(
        """
        def f():
            \"\"\"Doc.\"\"\"
            a = 1

            def g():
                return a
            return g


        class C:
            def m(self):
                pass
        """
    )
    assert _function_lengths(source, "mod") == {"mod.f": 5, "mod.f.g": 1, "mod.C.m": 1}


def test_the_effect_registry_keeps_its_order() -> None:
    """Every vocabulary listing and report follows the registry's order, which is the order in which
    ``camdegrade.effects`` imports its modules: moving a module must not reorder it (issue 45's step changed no
    diagnosis)."""
    assert [name for name in EFFECTS if name in REGISTERED][:14] == [
        "blur",
        "jpeg",
        "color",
        "tone",
        "denoise",
        "vignetting",
        "distortion",
        "chromatic_aberration",
        "misalignment",
        "learned_texture",
        "noise",
        "resolution",
        "frequency_response",
        "sharpen",
    ]
