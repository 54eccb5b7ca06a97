"""One (clean, captured) pair, how a pair is named and grouped into scenes, and the report of a discovery: the pairs
found and the files skipped, each with the reason (:func:`~camdegrade.pairs.discovery.discover_pairs`)."""

from __future__ import annotations

import os
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from camdegrade._support.text import printable

__all__ = ["Pair", "PairReport"]

# Why a file is skipped: a reason is "<category>" or "<category>: <detail>", and summaries group by category. The
# categories every reader shares are here; discovery and the manifest name their own.
MISSING = "missing file"
UNREADABLE = "unreadable"
TOO_SMALL = "too small"

_SEPARATORS = "_-. "

#: The files a discovery skips, each with its reason.
Skipped = list[tuple[Path | str, str]]


@dataclass(frozen=True)
class Pair:
    """One clean image and its capture.

    ``name`` is unique within a discovery (the relative path without extension); ``scene`` groups pairs that show
    the same content, for validation splits; ``meta`` holds extra manifest columns; ``crop_to`` is the common
    ``(height, width)`` both images are centre-cropped to when they differ in size (``size_mismatch="crop"``).
    """

    clean: Path
    captured: Path
    name: str
    scene: str
    meta: dict[str, str] = field(default_factory=dict, hash=False)
    crop_to: tuple[int, int] | None = None


@dataclass
class PairReport:
    """The pairs found and the files skipped, each with the reason (``"<category>: <detail>"``)."""

    pairs: list[Pair]
    skipped: list[tuple[Path | str, str]] = field(default_factory=list)
    source: Path | None = None
    layout: str = ""

    def summary(self, max_per_reason: int | None = 20) -> str:
        """Multi-line human-readable report: counts, then the skipped files grouped by reason."""
        where = f" in {printable(self.source)} ({self.layout})" if self.source is not None else ""
        lines = [f"{_count(len(self.pairs), 'pair')} found{where}, {len(self.skipped)} skipped"]
        cropped = sum(pair.crop_to is not None for pair in self.pairs)
        if cropped:
            lines.append(
                f"{_count(cropped, 'pair')} with images of different sizes will be centre-cropped to the common size"
            )
        groups: dict[str, list[str]] = defaultdict(list)
        root = self._root()
        for path, reason in self.skipped:
            category, _, detail = reason.partition(": ")
            shown = _display(path, root)
            if root is not None:
                detail = detail.replace(f"{root}{os.sep}", "")
            groups[category].append(printable(f"{shown}: {detail}" if detail else shown))
        for category, entries in sorted(groups.items()):
            lines.append(f"  {category} ({len(entries)}):")
            shown_entries = entries if max_per_reason is None else entries[:max_per_reason]
            lines.extend(f"    {entry}" for entry in shown_entries)
            if len(entries) > len(shown_entries):
                lines.append(f"    ... and {len(entries) - len(shown_entries)} more")
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.summary()

    def _root(self) -> Path | None:
        if self.source is None:
            return None
        return self.source if self.source.is_dir() else self.source.parent


def scene_id(clean_stem: str, captured_stem: str) -> str:
    """The part of the two file stems that names the scene: ``001H``/``001L`` → ``001``, ``a_mean``/``a_real``
    → ``a``. Falls back to the clean stem when the stems share less than half of it."""
    length = next((i for i, (a, b) in enumerate(zip(clean_stem, captured_stem)) if a != b), None)
    shared = clean_stem[: min(len(clean_stem), len(captured_stem)) if length is None else length]
    shared = shared.rstrip(_SEPARATORS)
    return shared if shared and 2 * len(shared) >= len(clean_stem) else clean_stem


def relative_stem(path: Path, base: Path) -> str:
    try:
        return path.relative_to(base).with_suffix("").as_posix()
    except ValueError:
        return path.with_suffix("").as_posix()


def _display(path: Path | str, root: Path | None) -> str:
    if isinstance(path, Path) and root is not None:
        try:
            return path.relative_to(root).as_posix()
        except ValueError:
            pass
    return str(path)


def _count(number: int, noun: str) -> str:
    return f"{number} {noun}" if number == 1 else f"{number} {noun}s"


def size_text(size: Sequence[int]) -> str:
    height, width = size
    return f"{width}x{height} px"
