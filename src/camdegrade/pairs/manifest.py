"""A CSV manifest of pairs: ``clean`` and ``captured`` columns (paths relative to the CSV), other columns kept in
``Pair.meta``, a ``scene`` column setting the pair's scene; every row that cannot be used is reported."""

from __future__ import annotations

import codecs
import csv
import os
from collections.abc import Iterable, Iterator
from pathlib import Path

from camdegrade.errors import PairsError
from camdegrade.pairs.pair import MISSING, UNREADABLE, Pair, Skipped, relative_stem, scene_id

__all__ = ["BAD_ROW", "DUPLICATE", "read_manifest"]

BAD_ROW = "bad manifest row"
DUPLICATE = "duplicate pair"


def read_manifest(manifest: Path) -> tuple[list[Pair], Skipped]:
    with manifest.open("rb") as handle:
        lines = _Utf8Lines(handle, manifest)
        try:
            return _read_manifest(csv.DictReader(lines), manifest)
        except csv.Error as error:  # e.g. a field longer than csv.field_size_limit()
            raise PairsError(f"manifest {str(manifest)!r} line {lines.number} is not valid CSV ({error})") from None


def _read_manifest(reader: csv.DictReader, manifest: Path) -> tuple[list[Pair], Skipped]:
    skipped: Skipped = []
    base = manifest.parent
    columns = {name.strip().lower(): name for name in reader.fieldnames or [] if name is not None}
    if "clean" not in columns or "captured" not in columns:
        raise PairsError(
            f"manifest {str(manifest)!r} must have columns 'clean' and 'captured', "
            f"got columns {list(reader.fieldnames or [])}"
        )
    candidates: dict[str, Pair] = {}
    first_line: dict[tuple[Path, Path], int] = {}
    for row in reader:
        where = f"{manifest.name} line {reader.line_num}"
        cells = {key: (row.get(original) or "").strip() for key, original in columns.items()}
        pair = _manifest_pair(base, cells, where, skipped)
        if pair is None:
            continue
        seen = first_line.setdefault((pair.clean, pair.captured), reader.line_num)
        if seen != reader.line_num:
            skipped.append((where, f"{DUPLICATE}: same files as line {seen}"))
            continue
        name = pair.name if pair.name not in candidates else f"{pair.name}~{relative_stem(pair.captured, base)}"
        candidates[name] = Pair(pair.clean, pair.captured, name, pair.scene, pair.meta)
    return list(candidates.values()), skipped


class _Utf8Lines:
    """A manifest's lines as text (UTF-8, a byte-order mark allowed), naming a line that is not UTF-8; ``number``
    is the last line read (where the csv module stopped, when it raises)."""

    def __init__(self, handle: Iterable[bytes], manifest: Path) -> None:
        self._lines = iter(handle)
        self._manifest = manifest
        self.number = 0

    def __iter__(self) -> Iterator[str]:
        return self

    def __next__(self) -> str:
        raw = next(self._lines)
        self.number += 1
        if self.number == 1 and raw.startswith(codecs.BOM_UTF8):
            raw = raw[len(codecs.BOM_UTF8) :]
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError as error:
            raise PairsError(
                f"manifest {str(self._manifest)!r} line {self.number} is not UTF-8 (byte 0x{raw[error.start]:02x} "
                f"at column {error.start + 1}); save the CSV as UTF-8"
            ) from None


def _manifest_pair(base: Path, cells: dict[str, str], where: str, skipped: Skipped) -> Pair | None:
    empty = [side for side in ("clean", "captured") if not cells[side]]
    if empty:
        skipped.append((where, f"{BAD_ROW}: empty {' and '.join(empty)} cell"))
        return None
    clean, captured = base / cells["clean"], base / cells["captured"]
    unusable = [path for path in (clean, captured) if not path.is_file()]
    for path in unusable:
        problem = f"{MISSING}: listed on {where}"
        if path.exists():  # a folder, FIFO or device where an image was expected
            problem = f"{UNREADABLE}: listed on {where} but not a regular file"
        skipped.append((path, problem))
    if unusable:
        return None
    if os.path.samefile(clean, captured):
        skipped.append((where, f"{BAD_ROW}: clean and captured are the same file ({cells['clean']})"))
        return None
    scene = cells.get("scene") or scene_id(clean.stem, captured.stem)
    meta = {key: value for key, value in cells.items() if key not in ("clean", "captured")}
    return Pair(clean, captured, relative_stem(clean, base), scene, meta)
