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
:func:`~camdegrade.pairs.pairset.load_pair` centre-crops both images to their common size.

Loading the pairs and splitting them by scene belong to the pair set (:mod:`camdegrade.pairs.pairset`).
"""

from __future__ import annotations

import os
from collections import defaultdict
from collections.abc import Iterable
from pathlib import Path
from typing import Literal

from camdegrade.errors import PairsError
from camdegrade.io import IMAGE_EXTENSIONS, iter_images, read_image_size
from camdegrade.pairs.manifest import read_manifest
from camdegrade.pairs.pair import TOO_SMALL, UNREADABLE, Pair, PairReport, Skipped, scene_id, size_text

__all__ = ["discover_pairs", "filter_pairs"]

NO_CAPTURED = "no captured partner"
NO_CLEAN = "no clean partner"
AMBIGUOUS = "ambiguous stem"
NO_SUFFIX = "matches neither suffix"
SIZE_MISMATCH = "size mismatch"


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


def _collect(root: Path, clean_suffix: str | None, captured_suffix: str | None) -> tuple[str, list[Pair], Skipped]:
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
        return ("CSV manifest", *read_manifest(root))
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


def _from_folders(root: Path) -> tuple[list[Pair], Skipped]:
    skipped: Skipped = []
    clean = _index(root / "clean", skipped, "clean")
    captured = _index(root / "captured", skipped, "captured")
    return _match(clean, captured, skipped), skipped


def _from_suffixes(root: Path, clean_suffix: str, captured_suffix: str) -> tuple[list[Pair], Skipped]:
    skipped: Skipped = []
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


def _index(folder: Path, skipped: Skipped, side: str) -> dict[str, Path]:
    by_key: dict[str, list[Path]] = defaultdict(list)
    for path in iter_images(folder):
        by_key[_key(path, folder)].append(path)
    return _unique(by_key, skipped, side)


def _unique(by_key: dict[str, list[Path]], skipped: Skipped, side: str) -> dict[str, Path]:
    unique: dict[str, Path] = {}
    for key, paths in by_key.items():
        if len(paths) == 1:
            unique[key] = paths[0]
            continue
        names = ", ".join(path.name for path in paths)
        skipped.extend((path, f"{AMBIGUOUS}: {len(paths)} {side} files share it ({names})") for path in paths)
    return unique


def _match(clean: dict[str, Path], captured: dict[str, Path], skipped: Skipped) -> list[Pair]:
    skipped.extend((path, NO_CAPTURED) for key, path in clean.items() if key not in captured)
    skipped.extend((path, NO_CLEAN) for key, path in captured.items() if key not in clean)
    return [
        Pair(path, captured[key], key, scene_id(path.stem, captured[key].stem), {})
        for key, path in clean.items()
        if key in captured
    ]


def _check_candidates(candidates: list[Pair], skipped: Skipped, min_size: int, size_mismatch: str) -> list[Pair]:
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


def _key(path: Path, root: Path) -> str:
    return path.relative_to(root).with_suffix("").as_posix()
