"""The README and docs/ hold together: every relative link points at a file (and a heading) that exists, every
docs page is reachable from the README, and the README stays a short first page."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
#: A markdown link or image target, or an HTML src/href; external and mail links are left out below.
LINK = re.compile(r"\]\(([^)\s]+)\)|(?:src|href)=\"([^\"]+)\"")


def _targets(text: str) -> list[str]:
    text = re.sub(r"```.*?```", "", text, flags=re.DOTALL)  # code blocks hold no links
    return [a or b for a, b in LINK.findall(text) if not re.match(r"[a-z]+:", a or b)]


def _anchor(heading: str) -> str:
    """GitHub's id for a heading: lower case, punctuation dropped (hyphens and underscores kept), spaces → '-'."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def _anchors(page: Path) -> set[str]:
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.DOTALL)
    return {_anchor(line.lstrip("#")) for line in text.splitlines() if line.startswith("#")}


@pytest.mark.parametrize("page", PAGES, ids=lambda page: page.name)
def test_relative_links_resolve(page: Path) -> None:
    broken = []
    for target in _targets(page.read_text()):
        path, _, anchor = target.partition("#")
        file = (page.parent / path).resolve() if path else page
        if not file.exists() or (anchor and file.suffix == ".md" and anchor not in _anchors(file)):
            broken.append(target)
    assert not broken, broken


def test_every_docs_page_is_linked_from_the_readme() -> None:
    linked = {(ROOT / target.partition("#")[0]).resolve() for target in _targets((ROOT / "README.md").read_text())}
    assert not [page.name for page in PAGES[1:] if page.resolve() not in linked]


def test_the_readme_is_a_first_page() -> None:
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 120
    assert "make demo" in text and re.search(r"^make test\b", text, re.MULTILINE) and "make test-all" in text


def _recipe(target: str) -> str:
    """The commands of a Makefile target."""
    found = re.search(rf"^{target}:.*\n((?:\t.*\n)+)", (ROOT / "Makefile").read_text(), flags=re.MULTILINE)
    assert found, target
    return found.group(1)


def test_make_test_is_the_fast_tier_and_ci_runs_everything() -> None:
    assert '-m "not slow"' in _recipe("test")
    assert "-m pytest" in _recipe("test-all") and "not slow" not in _recipe("test-all")
    ci = [line.split()[:2] for line in (ROOT / ".ci" / "run").read_text().splitlines() if line.startswith("make ")]
    assert ci == [["make", "test-all"], ["make", "lint"]]
    assert "experiments" in _recipe("lint")


@pytest.mark.parametrize("name", ["fitting.md", "diagnosis.md"])
def test_the_how_to_pages_stay_short(name: str) -> None:
    """How to run it, what it prints, what to do about it; the measurements live in results.md."""
    text = (ROOT / "docs" / name).read_text()
    assert len(text.splitlines()) <= 250 and "results.md#" in text


def test_the_link_check_can_fail() -> None:
    assert _targets('[a](docs/x.md#y) [b](https://e.org) <img src="p.png">\n```\n[c](z.md)\n```') == [
        "docs/x.md#y",
        "p.png",
    ]
    assert _anchor("How long it takes on a CPU") == "how-long-it-takes-on-a-cpu"
    assert _anchor("A faster profile: `camdegrade distill`") == "a-faster-profile-camdegrade-distill"


# --- what the docs show is the public API ----------------------------------------------------------------------

#: The modules a function shown in docs/usage.md and docs/fitting.md may come from.
PUBLIC_HOMES = ("camdegrade", "camdegrade.fitting", "camdegrade.diagnose")


def _python_blocks(page: Path) -> list[str]:
    return re.findall(r"```python\n(.*?)```", page.read_text(), flags=re.DOTALL)


def _exported(module: str) -> set[str]:
    """A public home's ``__all__``, read from its source (no import, no torch)."""
    path = ROOT / "src" / Path(*module.split(".")) / "__init__.py"
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, ast.Assign) and any(getattr(target, "id", "") == "__all__" for target in node.targets):
            return {element.value for element in node.value.elts}
    raise AssertionError(f"{module} has no __all__")


def _camdegrade_uses(code: str) -> list[tuple[str, str]]:
    """``(module, name)`` for every camdegrade name a code block imports or reaches through a module attribute."""
    uses = []
    for node in ast.walk(ast.parse(code)):
        if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "camdegrade":
            uses += [(node.module, alias.name) for alias in node.names]
        elif isinstance(node, ast.Import):
            uses += [(alias.name, "") for alias in node.names if alias.name.split(".")[0] == "camdegrade"]
        elif isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "camdegrade":
            uses.append(("camdegrade", node.attr))
    return uses


@pytest.mark.parametrize("name", ["usage.md", "fitting.md"])
def test_every_function_the_page_shows_comes_from_a_public_home(name: str) -> None:
    blocks = _python_blocks(ROOT / "docs" / name)
    assert blocks, name
    uses = [use for block in blocks for use in _camdegrade_uses(block)]
    assert uses, name
    outside = [use for use in uses if use[0] not in PUBLIC_HOMES]
    assert not outside, f"{name} imports from {outside}; show it from {PUBLIC_HOMES}"
    unknown = [use for use in uses if use[1] and use[1] not in _exported(use[0])]
    assert not unknown, f"{name} shows names its module does not export: {unknown}"


def test_the_public_home_check_can_fail() -> None:
    code = (
        "from camdegrade.fitting.distill import distill_profile\nimport camdegrade.io\nimport camdegrade\ncamdegrade.x"
    )
    assert _camdegrade_uses(code) == [
        ("camdegrade.fitting.distill", "distill_profile"),
        ("camdegrade.io", ""),
        ("camdegrade", ""),
        ("camdegrade", "x"),
    ]
    assert "fit_unpaired" in _exported("camdegrade") and "PairSet" in _exported("camdegrade.fitting")
