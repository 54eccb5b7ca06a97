"""The pair options of ``fit`` and ``diagnose`` (the loading options of :meth:`~camdegrade.fitting.PairSet.load`)
and their one discovery: the command finds the pairs once, keeps its outputs off their files and passes the
report on."""

from __future__ import annotations

import argparse
from pathlib import Path

from camdegrade.cli._common import positive_int

#: What PAIRS can be, for the commands' descriptions.
PAIRS_LAYOUTS = (
    "a folder with clean/ and captured/ (matching relative names), a CSV manifest with clean,captured columns, or "
    "a folder plus --clean-suffix/--captured-suffix"
)


def add_pair_options(parser: argparse.ArgumentParser, *, loading: bool) -> None:
    """``--clean-suffix``, ``--captured-suffix`` and ``--max-pairs``; with ``loading``, also ``--strict``,
    ``--size-mismatch`` and ``--align``."""
    parser.add_argument("--clean-suffix", default=None, help="e.g. _mean (with --captured-suffix)")
    parser.add_argument("--captured-suffix", default=None, help="e.g. _real, or _copy for the paper's layout")
    parser.add_argument("--max-pairs", type=positive_int, default=None, help="use at most this many pairs (by name)")
    if not loading:
        return
    parser.add_argument(
        "--strict",
        action="store_true",
        help="treat every warning as an error: fail on any unmatched, unreadable or tiny file before training, "
        "and write no profile that has a warning (one that does worse than the identity on the validation pairs; "
        "with --unpaired, one whose own check of noise and spectrum fails)",
    )
    parser.add_argument("--align", action="store_true", help="register each pair (sub-pixel shift) before training")
    parser.add_argument(
        "--size-mismatch",
        choices=("skip", "crop"),
        default="skip",
        help="pairs whose images differ in size: skip them (default) or centre-crop both to the common size",
    )


def discover(args: argparse.Namespace):
    """The discovery report of ``args.pairs`` with the command's options (the only discovery of the command)."""
    from camdegrade.pairs.discovery import discover_pairs

    return discover_pairs(
        args.pairs,
        clean_suffix=args.clean_suffix,
        captured_suffix=args.captured_suffix,
        strict=getattr(args, "strict", False),
        size_mismatch=getattr(args, "size_mismatch", "skip"),
    )


def report_files(report, source: Path) -> list[Path]:
    """Every file a discovery report names (and the manifest itself), to keep outputs off them."""
    files = [path for pair in report.pairs for path in (pair.clean, pair.captured)]
    return [*files, source] if source.is_file() else files
