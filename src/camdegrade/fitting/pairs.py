"""Find (clean, captured) image pairs for fitting a camera profile, and report the files that cannot be used.

Three layouts are understood (see :func:`discover_pairs`):

* a folder holding ``clean/`` and ``captured/``; files pair up when their paths relative to those folders match
  without the extension (``clean/a/b.png`` ↔ ``captured/a/b.JPG``);
* one folder (searched recursively) plus suffix rules: ``X_mean.JPG`` ↔ ``X_real.JPG`` for
  ``clean_suffix="_mean", captured_suffix="_real"``, or ``X.jpg`` ↔ ``X_copy.jpg`` for ``clean_suffix=""``,
  ``captured_suffix="_copy"``;
* a CSV manifest with ``clean`` and ``captured`` columns, paths relative to the CSV; other columns are kept in
  ``Pair.meta`` and a ``scene`` column sets the pair's scene.

Stems are compared case-sensitively, extensions case-insensitively. Pairs whose images differ in size are
skipped by default, because a capture of another size usually shows another field of view and a centre crop
would silently misalign it; ``size_mismatch="crop"`` keeps them and
:func:`~camdegrade.fitting.pairset.load_pair` centre-crops both images to their common size.

Loading the pairs and splitting them by scene belong to the pair set (:mod:`camdegrade.fitting.pairset`).
"""

from __future__ import annotations

import codecs
import csv
import os
from collections import defaultdict
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from camdegrade._text import printable
from camdegrade.errors import PairsError
from camdegrade.io import IMAGE_EXTENSIONS, iter_images, read_image_size

__all__ = ["Pair", "PairReport", "discover_pairs", "filter_pairs"]

# Reason categories; a reason is "<category>" or "<category>: <detail>", and summaries group by category.
NO_CAPTURED = "no captured partner"
NO_CLEAN = "no clean partner"
AMBIGUOUS = "ambiguous stem"
NO_SUFFIX = "matches neither suffix"
MISSING = "missing file"
BAD_ROW = "bad manifest row"
DUPLICATE = "duplicate pair"
UNREADABLE = "unreadable"
TOO_SMALL = "too small"
SIZE_MISMATCH = "size mismatch"

_SEPARATORS = "_-. "


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


def discover_pairs(
    source: str | os.PathLike[str],
    *,
    clean_suffix: str | None = None,
    captured_suffix: str | None = None,
    strict: bool = False,
    min_size: int = 16,
    check_images: bool = True,
    size_mismatch: Literal["skip", "crop"] = "skip",
) -> PairReport:
    """Find (clean, captured) pairs in ``source`` and report every file that cannot be used.

    Args:
        source: a folder holding ``clean/`` and ``captured/``; a folder to search with suffix rules (give
            ``clean_suffix`` and/or ``captured_suffix``; a missing one means the empty suffix); or a ``.csv``
            manifest with ``clean`` and ``captured`` columns.
        clean_suffix, captured_suffix: stem suffixes marking the two sides, e.g. ``"_mean"`` and ``"_real"``.
        strict: raise :class:`PairsError` listing every problem instead of skipping files.
        min_size: images whose height or width is below this are skipped as too small.
        check_images: open each file's header (no decoding) to catch unreadable, tiny and size-mismatched
            images now rather than in the middle of training.
        size_mismatch: ``"skip"`` pairs whose images differ in size, or ``"crop"`` them to the common size.

    Returns:
        A :class:`PairReport`; its pairs are sorted by name and each name is unique.

    Raises:
        PairsError: the source is unusable, no pair was found, or ``strict`` and some file was skipped.
    """
    root = Path(source)
    if size_mismatch not in ("skip", "crop"):
        raise PairsError(f"size_mismatch must be 'skip' or 'crop', got size_mismatch={size_mismatch!r}")
    if isinstance(min_size, bool) or not isinstance(min_size, int) or min_size < 1:
        raise PairsError(f"min_size must be a positive integer, got min_size={min_size!r}")
    layout, candidates, skipped = _collect(root, clean_suffix, captured_suffix)
    pairs = _check_candidates(candidates, skipped, min_size, size_mismatch) if check_images else candidates
    report = PairReport(
        pairs=sorted(pairs, key=lambda pair: pair.name),
        skipped=sorted(skipped, key=lambda item: (item[1].partition(": ")[0], str(item[0]))),
        source=root,
        layout=layout,
    )
    if not report.pairs:
        raise PairsError(f"no usable (clean, captured) pairs found; looked for {layout}.\n{report.summary()}")
    if strict and report.skipped:
        raise PairsError(
            f"{report.summary(max_per_reason=None)}\n"
            "strict mode: fix or remove these files, or run without strict to skip them"
        )
    return report


def filter_pairs(pairs: Iterable[Pair], *, path_contains: str | None = None, **meta: str) -> list[Pair]:
    """Pairs whose ``meta`` has every given value and whose clean or captured path contains ``path_contains``.

    Example: the City100 iPhone X pairs of the shared real-pairs manifest::

        report = discover_pairs("real-pairs/pairs.csv")
        iphone = filter_pairs(report.pairs, subset="city100_iPhoneX")
    """
    selected = []
    for pair in pairs:
        if any(pair.meta.get(key) != value for key, value in meta.items()):
            continue
        if path_contains is not None and not any(
            path_contains in path.as_posix() for path in (pair.clean, pair.captured)
        ):
            continue
        selected.append(pair)
    return selected


_Skipped = list[tuple[Path | str, str]]


def _collect(root: Path, clean_suffix: str | None, captured_suffix: str | None) -> tuple[str, list[Pair], _Skipped]:
    """Pick the layout of ``root`` and list its candidate pairs (images not yet checked) and skipped files."""
    use_suffixes = clean_suffix is not None or captured_suffix is not None
    if not root.exists():
        raise PairsError(f"source {str(root)!r} does not exist; {_LAYOUTS}")
    if not root.is_file() and not root.is_dir():  # never opened: a FIFO would block the reader
        raise PairsError(f"source {str(root)!r} is not a regular file or folder (a device, FIFO or socket); {_LAYOUTS}")
    if root.is_file():
        if root.suffix.lower() != ".csv":
            raise PairsError(f"source {str(root)!r} is a file but not a .csv manifest; {_LAYOUTS}")
        if use_suffixes:
            raise PairsError("clean_suffix and captured_suffix apply to folders, not to a CSV manifest")
        return ("CSV manifest", *_from_manifest(root))
    if use_suffixes:
        suffixes = _check_suffixes(clean_suffix or "", captured_suffix or "")
        layout = f"suffix rules clean={suffixes[0]!r} captured={suffixes[1]!r}"
        return (layout, *_from_suffixes(root, *suffixes))
    if (root / "clean").is_dir() and (root / "captured").is_dir():
        return ("clean/ and captured/ folders", *_from_folders(root))
    raise PairsError(_nothing_recognised(root))


_LAYOUTS = (
    "expected a folder holding clean/ and captured/, a folder plus clean_suffix/captured_suffix "
    "(CLI: --clean-suffix/--captured-suffix), or a .csv manifest with clean and captured columns"
)


def _from_folders(root: Path) -> tuple[list[Pair], _Skipped]:
    skipped: _Skipped = []
    clean = _index(root / "clean", skipped, "clean")
    captured = _index(root / "captured", skipped, "captured")
    return _match(clean, captured, skipped), skipped


def _from_suffixes(root: Path, clean_suffix: str, captured_suffix: str) -> tuple[list[Pair], _Skipped]:
    skipped: _Skipped = []
    sides: dict[str, dict[str, list[Path]]] = {"clean": defaultdict(list), "captured": defaultdict(list)}
    rules = sorted([("clean", clean_suffix), ("captured", captured_suffix)], key=lambda rule: -len(rule[1]))
    for path in iter_images(root):
        stem = _key(path, root)
        for side, suffix in rules:
            if stem.endswith(suffix) and len(Path(stem).name) > len(suffix):
                sides[side][stem[: len(stem) - len(suffix)]].append(path)
                break
        else:
            skipped.append((path, f"{NO_SUFFIX}: neither {clean_suffix!r} nor {captured_suffix!r}"))
    clean = _unique(sides["clean"], skipped, "clean")
    captured = _unique(sides["captured"], skipped, "captured")
    return _match(clean, captured, skipped), skipped


def _from_manifest(manifest: Path) -> tuple[list[Pair], _Skipped]:
    with manifest.open("rb") as handle:
        lines = _Utf8Lines(handle, manifest)
        try:
            return _read_manifest(csv.DictReader(lines), manifest)
        except csv.Error as error:  # e.g. a field longer than csv.field_size_limit()
            raise PairsError(f"manifest {str(manifest)!r} line {lines.number} is not valid CSV ({error})") from None


def _read_manifest(reader: csv.DictReader, manifest: Path) -> tuple[list[Pair], _Skipped]:
    skipped: _Skipped = []
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
        name = pair.name if pair.name not in candidates else f"{pair.name}~{_relative_stem(pair.captured, base)}"
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


def _manifest_pair(base: Path, cells: dict[str, str], where: str, skipped: _Skipped) -> Pair | None:
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
    scene = cells.get("scene") or _scene_id(clean.stem, captured.stem)
    meta = {key: value for key, value in cells.items() if key not in ("clean", "captured")}
    return Pair(clean, captured, _relative_stem(clean, base), scene, meta)


def _index(folder: Path, skipped: _Skipped, side: str) -> dict[str, Path]:
    by_key: dict[str, list[Path]] = defaultdict(list)
    for path in iter_images(folder):
        by_key[_key(path, folder)].append(path)
    return _unique(by_key, skipped, side)


def _unique(by_key: dict[str, list[Path]], skipped: _Skipped, side: str) -> dict[str, Path]:
    unique: dict[str, Path] = {}
    for key, paths in by_key.items():
        if len(paths) == 1:
            unique[key] = paths[0]
            continue
        names = ", ".join(path.name for path in paths)
        skipped.extend((path, f"{AMBIGUOUS}: {len(paths)} {side} files share it ({names})") for path in paths)
    return unique


def _match(clean: dict[str, Path], captured: dict[str, Path], skipped: _Skipped) -> list[Pair]:
    skipped.extend((path, NO_CAPTURED) for key, path in clean.items() if key not in captured)
    skipped.extend((path, NO_CLEAN) for key, path in captured.items() if key not in clean)
    return [
        Pair(path, captured[key], key, _scene_id(path.stem, captured[key].stem), {})
        for key, path in clean.items()
        if key in captured
    ]


def _check_candidates(candidates: list[Pair], skipped: _Skipped, min_size: int, size_mismatch: str) -> list[Pair]:
    sizes: dict[Path, tuple[int, int] | str] = {}
    for path in {p for pair in candidates for p in (pair.clean, pair.captured)}:
        sizes[path] = _probe(path)
    reported: set[Path] = set()
    kept = []
    for pair in candidates:
        problems = []
        for path in (pair.clean, pair.captured):
            size = sizes[path]
            if isinstance(size, str):
                problems.append((path, f"{UNREADABLE}: {size}"))
            elif min(size) < min_size:
                problems.append((path, f"{TOO_SMALL}: {size_text(size)} (min_size={min_size})"))
        if problems:
            skipped.extend(problem for problem in problems if problem[0] not in reported)
            reported.update(path for path, _ in problems)
            continue
        clean_size, captured_size = sizes[pair.clean], sizes[pair.captured]
        if clean_size == captured_size:
            kept.append(pair)
            continue
        common = (min(clean_size[0], captured_size[0]), min(clean_size[1], captured_size[1]))
        if size_mismatch == "crop" and min(common) >= min_size:
            kept.append(Pair(pair.clean, pair.captured, pair.name, pair.scene, pair.meta, crop_to=common))
            continue
        skipped.append(
            (
                pair.clean,
                f"{SIZE_MISMATCH}: clean {size_text(clean_size)}, captured {size_text(captured_size)} "
                f"(captured: {pair.captured})",
            )
        )
    return kept


def _probe(path: Path) -> tuple[int, int] | str:
    """``(height, width)`` after EXIF orientation, or why the file cannot be read."""
    try:
        return read_image_size(path)
    except OSError as error:
        return str(error)


def _check_suffixes(clean_suffix: str, captured_suffix: str) -> tuple[str, str]:
    if clean_suffix == captured_suffix:
        raise PairsError(
            f"clean_suffix and captured_suffix must differ, got {clean_suffix!r} for both "
            "(e.g. clean_suffix='_mean', captured_suffix='_real', or clean_suffix='', captured_suffix='_copy')"
        )
    for name, suffix in (("clean_suffix", clean_suffix), ("captured_suffix", captured_suffix)):
        if Path(suffix).suffix.lower() in IMAGE_EXTENSIONS:
            raise PairsError(f"{name} is matched against the stem, without the extension; got {name}={suffix!r}")
    return clean_suffix, captured_suffix


def _nothing_recognised(root: Path) -> str:
    folders = sorted(child.name + "/" for child in root.iterdir() if child.is_dir() and not child.name.startswith("."))
    images = list(iter_images(root))
    found = f"found {len(images)} image files"
    if images:
        found += " (e.g. " + ", ".join(path.relative_to(root).as_posix() for path in images[:3]) + ")"
    if folders:
        found += f" and folders {folders[:10]}"
    missing = [name for name in ("clean", "captured") if not (root / name).is_dir()]
    return (
        f"no (clean, captured) layout recognised in {str(root)!r}: {_LAYOUTS}. "
        f"Missing folder(s) {', '.join(m + '/' for m in missing)}; {found}"
    )


def _scene_id(clean_stem: str, captured_stem: str) -> str:
    """The part of the two file stems that names the scene: ``001H``/``001L`` → ``001``, ``a_mean``/``a_real``
    → ``a``. Falls back to the clean stem when the stems share less than half of it."""
    length = next((i for i, (a, b) in enumerate(zip(clean_stem, captured_stem)) if a != b), None)
    shared = clean_stem[: min(len(clean_stem), len(captured_stem)) if length is None else length]
    shared = shared.rstrip(_SEPARATORS)
    return shared if shared and 2 * len(shared) >= len(clean_stem) else clean_stem


def _key(path: Path, root: Path) -> str:
    return path.relative_to(root).with_suffix("").as_posix()


def _relative_stem(path: Path, base: Path) -> str:
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
