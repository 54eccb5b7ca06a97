"""The README and docs/ hold together: every relative link points at a file (and a heading) that exists, every
docs page is reachable from the README, and the README stays a short first page."""

from __future__ import annotations

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
    assert "make demo" in text and "make test" in text


def test_the_link_check_can_fail() -> None:
    assert _targets('[a](docs/x.md#y) [b](https://e.org) <img src="p.png">\n```\n[c](z.md)\n```') == [
        "docs/x.md#y",
        "p.png",
    ]
    assert _anchor("How long it takes on a CPU") == "how-long-it-takes-on-a-cpu"
    assert _anchor("A faster profile: `camdegrade distill`") == "a-faster-profile-camdegrade-distill"
