"""The benches' markdown tables: a header, its alignment line and one line a row, written one way for every bench
(docs/results.md and docs/diagnosis.md paste them as they are printed)."""

from __future__ import annotations

from collections.abc import Collection, Iterable, Sequence

__all__ = ["markdown_table"]


def markdown_table(columns: Sequence[str], rows: Iterable[Sequence[str]], numeric: Collection[str] = ()) -> list[str]:
    """The lines of a markdown table: ``columns`` as the header (those in ``numeric`` right-aligned), then one line
    per row of cells (already formatted)."""
    align = "".join("---:|" if column in numeric else "---|" for column in columns)
    return [_line(columns), "|" + align, *(_line(cells) for cells in rows)]


def _line(cells: Sequence[str]) -> str:
    return "| " + " | ".join(cells) + " |"
