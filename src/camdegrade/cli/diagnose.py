"""``camdegrade diagnose PROFILE PAIRS``: where a profile's simulations differ from real captures
(:func:`~camdegrade.diagnose.diagnose`; unpaired with ``--real``). Its options follow ``diagnose``'s keywords
(a test holds them to it). The pairs are discovered once and the report passed on."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from camdegrade._support.text import printable
from camdegrade.cli._common import (
    add_profile,
    add_threads,
    check_outputs,
    check_suffix,
    fail_on_unreadable,
    image_files,
    say,
    seed,
    share,
)
from camdegrade.cli._pairs import PAIRS_LAYOUTS, add_pair_options, discover, report_files

__all__ = ["NOT_OFFERED", "add_parser", "run"]

#: ``diagnose`` keywords the command does not offer, and why.
NOT_OFFERED = {
    "held_out": "the command splits PAIRS by scene",
    "max_added": "the library's default",
    "log": "progress goes to stdout unless --quiet",
}


def add_parser(commands: argparse._SubParsersAction) -> None:
    diagnose = commands.add_parser(
        "diagnose",
        help="find where a profile's simulations differ from REAL captures, and which effect closes the gap",
        description=f"Diagnose the sim-to-real gap of PROFILE on REAL (clean, captured) PAIRS it was not fitted on "
        f"({PAIRS_LAYOUTS}). The pairs are split by scene into a calibration part (candidate effects are fitted on "
        "it) and a held-out part (every gap is measured on it). With --real, PAIRS is a folder of clean images and "
        "--real a folder of captures of other scenes (unpaired: the distribution-level part only).",
    )
    add_profile(diagnose, "built-in profile name or .safetensors path")
    diagnose.add_argument("pairs", type=Path, help="pairs folder or CSV manifest (with --real: clean images folder)")
    diagnose.add_argument("--json", type=Path, default=None, help="write the JSON report here")
    diagnose.add_argument("--html", type=Path, default=None, help="write the one-file HTML report here")
    diagnose.add_argument("--out-profile", type=Path, default=None, help="write the profile with the accepted changes")
    diagnose.add_argument("--seed", type=seed, default=0, help="seeds the split, simulations and bootstrap")
    diagnose.add_argument("--real", type=Path, default=None, help="unpaired mode: a folder of real captures")
    diagnose.add_argument("--calibration-fraction", type=share(False), default=0.5, help="share of scenes for fitting")
    diagnose.add_argument("--candidates", nargs="+", default=None, help="effect names to try adding (default: all)")
    diagnose.add_argument(
        "--kinds", nargs="+", default=None, help="kinds of change to try: add remove refit network (default: all)"
    )
    diagnose.add_argument(
        "--no-critic",
        dest="critic",
        action="store_false",
        help="skip the learned critic and its check of the accepted changes (faster)",
    )
    add_pair_options(diagnose, loading=False)
    add_threads(diagnose)
    diagnose.add_argument("--quiet", action="store_true", help="print only the verdict")


def run(args: argparse.Namespace) -> int:
    from camdegrade.profile import resolve_profile_path

    check_suffix("--out-profile", args.out_profile)
    outputs = {"--json": args.json, "--html": args.html, "--out-profile": args.out_profile}
    if args.real is not None:
        if args.out_profile is not None:
            raise ValueError("--out-profile needs paired data (nothing is fitted in unpaired mode with --real)")
        check_outputs(outputs, [resolve_profile_path(args.profile), *image_files(args.pairs), *image_files(args.real)])
        report = _unpaired(args)
    else:
        pairs = _discover_or_defer(args)
        found = report_files(pairs, args.pairs) if pairs is not None else [args.pairs] if args.pairs.is_file() else []
        check_outputs(outputs, [resolve_profile_path(args.profile), *found])
        report = _paired(args, pairs if pairs is not None else args.pairs)
    if args.quiet:
        print(report.verdict)
        skipped = getattr(report, "skipped", [])
        if skipped:  # a dropped pair is never silent, even with --quiet
            print(f"{len(skipped)} file(s) skipped while loading the pairs (see the JSON report's 'skipped')")
    _write(report, args)
    from camdegrade.pairs.pair import UNREADABLE

    unreadable = [entry for entry in getattr(report, "skipped", []) if entry["reason"].startswith(UNREADABLE)]
    fail_on_unreadable(unreadable, "the diagnosis used the other pairs")
    return 0


def _discover_or_defer(args: argparse.Namespace):
    """The pairs' discovery report, or ``None`` when the pairs cannot be found: ``diagnose`` then reports that,
    after refusing its own bad arguments (``--kinds``, ``--candidates``) first."""
    from camdegrade.errors import PairsError

    try:
        return discover(args)
    except (PairsError, OSError, ValueError):
        return None


def _paired(args: argparse.Namespace, pairs):
    from camdegrade.diagnose import diagnose

    return diagnose(
        args.profile,
        pairs,
        calibration_fraction=args.calibration_fraction,
        candidates=args.candidates,
        kinds=args.kinds,
        critic=args.critic,
        seed=args.seed,
        clean_suffix=args.clean_suffix,
        captured_suffix=args.captured_suffix,
        max_pairs=args.max_pairs,
        log=None if args.quiet else say,
    )


def _unpaired(args: argparse.Namespace):
    from camdegrade.diagnose.unpaired import diagnose_unpaired

    return diagnose_unpaired(args.profile, args.pairs, args.real, seed=args.seed, max_images=args.max_pairs)


def _write(report, args: argparse.Namespace) -> None:
    if args.json is not None:
        print(f"wrote {printable(report.write_json(args.json))}")
    if args.html is not None:
        print(f"wrote {printable(report.write_html(args.html))}")
    if args.out_profile is None:
        return
    if report.profile is None or not report.accepted:
        print("no change was accepted; --out-profile not written", file=sys.stderr)
    else:
        report.profile.save(args.out_profile)
        print(f"wrote {printable(args.out_profile)} ({', '.join(report.accepted)})")
