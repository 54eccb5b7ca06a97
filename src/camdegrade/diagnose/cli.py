"""``camdegrade diagnose PROFILE PAIRS``: the command-line front of :func:`camdegrade.diagnose.diagnose`.

``__main__`` registers it with ``add_diagnose_parser(commands)`` and dispatches ``"diagnose"`` to
:func:`run_diagnose`.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path


def add_diagnose_parser(commands: argparse._SubParsersAction) -> argparse.ArgumentParser:
    parser = commands.add_parser(
        "diagnose",
        help="find where a profile's simulations differ from REAL captures, and which effect closes the gap",
        description="Diagnose the sim-to-real gap of PROFILE on REAL (clean, captured) PAIRS it was not fitted on "
        "(a folder with clean/ and captured/, a CSV manifest, or a folder plus --clean-suffix/--captured-suffix). "
        "The pairs are split by scene into a calibration part (candidate effects are fitted on it) and a held-out "
        "part (every gap is measured on it). With --real, PAIRS is a folder of clean images and --real a folder of "
        "captures of other scenes (unpaired: the distribution-level part only).",
    )
    parser.add_argument("profile", help="built-in profile name or .safetensors path")
    parser.add_argument("pairs", type=Path, help="pairs folder or CSV manifest (with --real: clean images folder)")
    parser.add_argument("--json", type=Path, default=None, help="write the JSON report here")
    parser.add_argument("--html", type=Path, default=None, help="write the one-file HTML report here")
    parser.add_argument("--out-profile", type=Path, default=None, help="write the profile with the added effects")
    parser.add_argument("--seed", type=int, default=0, help="seeds the split, simulations and bootstrap")
    parser.add_argument("--real", type=Path, default=None, help="unpaired mode: a folder of real captures")
    parser.add_argument("--calibration-fraction", type=float, default=0.5, help="share of scenes for fitting")
    parser.add_argument("--max-pairs", type=int, default=None, help="use at most this many pairs")
    parser.add_argument("--candidates", nargs="+", default=None, help="effect names to try (default: all)")
    parser.add_argument("--clean-suffix", default=None)
    parser.add_argument("--captured-suffix", default=None)
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    parser.add_argument("--quiet", action="store_true", help="print only the verdict")
    return parser


def run_diagnose(args: argparse.Namespace) -> int:
    import torch

    from camdegrade.diagnose import diagnose
    from camdegrade.diagnose.unpaired import diagnose_unpaired

    if args.out_profile is not None and args.out_profile.suffix != ".safetensors":
        raise ValueError(f"--out-profile must end in .safetensors, got {str(args.out_profile)!r}")
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    log = None if args.quiet else print
    if args.real is not None:
        if args.out_profile is not None:
            raise ValueError("--out-profile needs paired data (nothing is fitted in unpaired mode with --real)")
        report = diagnose_unpaired(args.profile, args.pairs, args.real, seed=args.seed, max_images=args.max_pairs)
    else:
        report = diagnose(
            args.profile,
            args.pairs,
            calibration_fraction=args.calibration_fraction,
            candidates=args.candidates,
            seed=args.seed,
            clean_suffix=args.clean_suffix,
            captured_suffix=args.captured_suffix,
            max_pairs=args.max_pairs,
            log=log,
        )
    if args.quiet:
        print(report.verdict)
    if args.json is not None:
        print(f"wrote {report.write_json(args.json)}")
    if args.html is not None:
        print(f"wrote {report.write_html(args.html)}")
    if args.out_profile is not None:
        if report.profile is None or not report.added:
            print("no effect was added; --out-profile not written", file=sys.stderr)
        else:
            report.profile.save(args.out_profile)
            print(f"wrote {args.out_profile} (added: {', '.join(report.added)})")
    return 0


def standalone(argv: Sequence[str] | None = None) -> int:
    """Run ``diagnose`` alone, with the CLI's error handling (used before ``__main__`` registers it)."""
    from camdegrade.errors import CamdegradeError

    parser = argparse.ArgumentParser(prog="camdegrade")
    commands = parser.add_subparsers(dest="command", required=True)
    add_diagnose_parser(commands)
    args = parser.parse_args(["diagnose", *(sys.argv[1:] if argv is None else argv)])
    try:
        return run_diagnose(args)
    except (CamdegradeError, OSError, ValueError) as error:
        print(f"{parser.prog}: error: {error}", file=sys.stderr)
        return 1
