"""``camdegrade simulate PRESET INPUT OUT_DIR``: a pairs folder (clean/, captured/) made with a virtual camera."""

from __future__ import annotations

import argparse
from pathlib import Path

from camdegrade._support.text import printable
from camdegrade.cli._common import add_threads, list_failures, positive_int, seed
from camdegrade.errors import BatchError

__all__ = ["add_parser", "run"]


def add_parser(commands: argparse._SubParsersAction) -> None:
    simulate = commands.add_parser(
        "simulate",
        help="make a pairs folder (clean/, captured/) with a virtual camera preset",
    )
    simulate.add_argument("preset", help="virtual camera preset, e.g. lowcost-robot")
    simulate.add_argument("input", type=Path, help="clean image file or folder")
    simulate.add_argument("out_dir", type=Path, help="output folder; gets clean/ and captured/")
    simulate.add_argument("--seed", type=seed, default=0)
    simulate.add_argument("--max-side", type=positive_int, default=None, help="downsize clean images larger than this")
    simulate.add_argument(
        "--overwrite",
        action="store_true",
        help="allow OUT_DIR inside the input folder (it is then not read as input); no option writes over an input",
    )
    add_threads(simulate)


def run(args: argparse.Namespace) -> int:
    from camdegrade.sim import simulate_pairs

    options = {"seed": args.seed, "max_side": args.max_side, "overwrite": args.overwrite}
    done = f"to {printable(args.out_dir)} (clean/, captured/) with preset {args.preset!r}"
    try:
        written = simulate_pairs(args.preset, args.input, args.out_dir, **options)
    except BatchError as error:
        print(f"wrote {len(error.done)} pair(s) {done}")
        list_failures(error.failed)
        raise BatchError(
            f"{len(error.failed)} of {len(error.failed) + len(error.done)} image(s) could not be simulated "
            "(listed above)",
            error.failed,
            error.done,
        ) from None
    print(f"wrote {len(written)} pair(s) {done}")
    return 0
