"""Command line: ``camdegrade apply|info|list ...`` (also ``python -m camdegrade``)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from camdegrade._version import __version__
from camdegrade.errors import CamdegradeError


def main_parser(prog: str | None = None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=prog,
        description="Make clean images look as if a specific camera had captured them.",
    )
    parser.add_argument("--version", action="version", version=f"camdegrade {__version__}")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    apply = commands.add_parser("apply", help="degrade an image file, or every image in a folder (recursively)")
    apply.add_argument("profile", help="built-in profile name (see 'camdegrade list') or .safetensors path")
    apply.add_argument("input", type=Path, help="image file or folder")
    apply.add_argument("output", type=Path, help="output file (for a file input) or folder (for a folder input)")
    apply.add_argument("--seed", type=int, default=0, help="seed of the random effects (default: 0)")
    apply.add_argument("--p", type=float, default=1.0, help="probability of degrading each image (default: 1)")
    apply.add_argument("--device", default="cpu", help="torch device to run on (default: cpu)")

    info = commands.add_parser("info", help="show a profile's network, effect chain, fitting record and quality")
    info.add_argument("profile", help="built-in profile name or .safetensors path")

    commands.add_parser("list", help="list the built-in profiles")
    return parser


def _run_apply(args: argparse.Namespace) -> int:
    from camdegrade.io import iter_images, read_image, write_image
    from camdegrade.transform import CameraDegrade

    degrade = CameraDegrade(args.profile, p=args.p, seed=args.seed)
    if args.input.is_dir():
        if args.output.exists() and not args.output.is_dir():
            raise ValueError(f"output must be a folder when input is a folder, got file {str(args.output)!r}")
        jobs = [(path, args.output / path.relative_to(args.input)) for path in iter_images(args.input)]
        if not jobs:
            raise ValueError(f"input folder {str(args.input)!r} holds no images")
    elif args.input.is_file():
        target = args.output / args.input.name if args.output.is_dir() else args.output
        jobs = [(args.input, target)]
    else:
        raise FileNotFoundError(f"input {str(args.input)!r} does not exist")
    for source, target in jobs:
        image = read_image(source).to(args.device)
        write_image(degrade(image).cpu(), target)
        print(f"{source} -> {target}")
    print(f"degraded {len(jobs)} image(s) with profile {degrade.profile.name or args.profile!r}")
    return 0


def _run_info(args: argparse.Namespace) -> int:
    from camdegrade.profile import load_profile

    print(load_profile(args.profile).describe())
    return 0


def _run_list(args: argparse.Namespace) -> int:
    from camdegrade.profile import list_profiles, load_profile

    for name in list_profiles():
        print(f"{name:24s} {load_profile(name).description}")
    return 0


_COMMANDS = {"apply": _run_apply, "info": _run_info, "list": _run_list}


def main(cli_args: Sequence[str] | None = None, prog: str | None = None) -> int:
    """Run the CLI with ``cli_args`` (default: ``sys.argv[1:]``); return the exit status."""
    parser = main_parser(prog)
    args = parser.parse_args(cli_args)
    try:
        return _COMMANDS[args.command](args)
    except (CamdegradeError, OSError, ValueError) as error:
        print(f"{parser.prog}: error: {error}", file=sys.stderr)
        return 1


def entrypoint() -> None:
    sys.exit(main())


if __name__ == "__main__":
    sys.exit(main(prog="python -m camdegrade"))
