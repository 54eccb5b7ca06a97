"""The public face: every public module (no ``_``-prefixed part in its dotted name) says what it exports with
``__all__``, and every name it lists is defined or imported there. Read from the source (no import): fast."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SOURCE = Path(__file__).resolve().parents[1] / "src"


def _module_name(path: Path) -> str:
    parts = path.relative_to(SOURCE).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _public_modules() -> list[Path]:
    modules = []
    for path in sorted((SOURCE / "camdegrade").rglob("*.py")):
        if not any(part.startswith("_") for part in _module_name(path).split(".")):
            modules.append(path)
    return modules


def _module_source(module: str) -> ast.Module:
    """The parsed source of the camdegrade module named ``module`` (a package's ``__init__.py``)."""
    path = SOURCE.joinpath(*module.split("."))
    return ast.parse((path / "__init__.py" if path.is_dir() else path.with_suffix(".py")).read_text())


def _declared(tree: ast.Module) -> list[str] | None:
    """The names of a module-level ``__all__ = [...]`` (or annotated), or of the ``__all__`` it imports from a module
    of its own (``from camdegrade.x import __all__ as __all__``, a package that re-exports one module), or None."""
    for node in tree.body:
        if isinstance(node, ast.ImportFrom) and any(alias.name == "__all__" for alias in node.names):
            return _declared(_module_source(node.module or ""))
        if isinstance(node, ast.Assign):
            targets = node.targets
        elif isinstance(node, ast.AnnAssign):
            targets = [node.target]
        else:
            continue
        if any(isinstance(target, ast.Name) and target.id == "__all__" for target in targets):
            return [element.value for element in node.value.elts]  # type: ignore[union-attr]
    return None


def _top_level(body: list[ast.stmt]) -> list[ast.stmt]:
    """The module's own statements, those under a top-level ``if`` or ``try`` (``TYPE_CHECKING``) included."""
    statements = []
    for node in body:
        statements.append(node)
        if isinstance(node, ast.If):
            statements += _top_level(node.body + node.orelse)
        elif isinstance(node, ast.Try):
            statements += _top_level(node.body + node.orelse + [s for h in node.handlers for s in h.body])
    return statements


def _bound(tree: ast.Module) -> set[str]:
    """Every name the module binds at its top level: definitions, assignments and imports."""
    names: set[str] = set()
    for node in _top_level(tree.body):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names.update(name.id for target in targets for name in ast.walk(target) if isinstance(name, ast.Name))
        elif isinstance(node, ast.ImportFrom) and [alias.name for alias in node.names] == ["*"]:
            names.update(_declared(_module_source(node.module or "")) or [])
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names.update((alias.asname or alias.name).split(".")[0] for alias in node.names)
    return names


PUBLIC = _public_modules()


def test_the_walk_finds_the_public_modules_and_leaves_out_the_private_ones() -> None:
    names = {_module_name(path) for path in PUBLIC}
    assert {"camdegrade", "camdegrade.transform", "camdegrade.network.inference", "camdegrade.fitting"} <= names
    assert not {"camdegrade._support.pixels", "camdegrade.cli._common", "camdegrade.__main__"} & names
    assert len(names) > 90


@pytest.mark.parametrize("path", PUBLIC, ids=_module_name)
def test_every_public_module_declares_what_it_exports(path: Path) -> None:
    tree = ast.parse(path.read_text())
    declared = _declared(tree)
    assert declared is not None, f"{_module_name(path)} has no __all__"
    assert len(declared) == len(set(declared)), declared
    missing = set(declared) - _bound(tree) - {"__version__"}
    if _module_name(path) == "camdegrade":  # its names are imported on first use (PEP 562): listed in _LAZY
        missing -= {element.value for element in _lazy_keys(tree)} | {"diagnose"}
    assert not missing, f"{_module_name(path)}.__all__ lists names it does not bind: {sorted(missing)}"


def _lazy_keys(tree: ast.Module) -> list[ast.Constant]:
    for node in tree.body:
        if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and node.target.id == "_LAZY":
            return node.value.keys  # type: ignore[union-attr,return-value]
    raise AssertionError("camdegrade/__init__.py has no _LAZY table")


def test_the_check_can_fail() -> None:
    assert _declared(ast.parse("x = 1")) is None
    assert _declared(ast.parse("__all__: list[str] = ['a']")) == ["a"]
    bound = _bound(ast.parse("from a import b as c\nimport d.e\ndef f(): g = 1\nclass H: pass"))
    assert bound == {"c", "d", "f", "H"}
    names_only = "from camdegrade.network.nets import __all__ as __all__"
    reexport = ast.parse(f"from camdegrade.network.nets import *\n{names_only}")
    assert "build_network" in _declared(reexport) and set(_declared(reexport)) <= _bound(reexport)
    assert "build_network" not in _bound(ast.parse(names_only))


def test_the_top_level_offers_the_workflows_and_their_argument_types() -> None:
    import camdegrade

    for name in ("PairSet", "FitConfig", "fit_profile", "fit_unpaired", "distill_profile", "diagnose"):
        assert name in camdegrade.__all__ and callable(getattr(camdegrade, name)), name
