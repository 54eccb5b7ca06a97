"""``camdegrade apply PROFILE INPUT OUTPUT``: degrade an image file, or every image in a folder (recursively)."""

from __future__ import annotations

import argparse
from pathlib import Path

from camdegrade._support.text import printable
from camdegrade.cli._common import add_profile, add_threads, list_failures, probability, seed
from camdegrade.errors import BatchError

__all__ = ["add_parser", "run"]


def add_parser(commands: argparse._SubParsersAction) -> None:
    apply = commands.add_parser("apply", help="degrade an image file, or every image in a folder (recursively)")
    add_profile(apply, "built-in profile name (see 'camdegrade list') or .safetensors path")
    apply.add_argument("input", type=Path, help="image file or folder")
    apply.add_argument("output", type=Path, help="output file (for a file input) or folder (for a folder input)")
    apply.add_argument("--seed", type=seed, default=0, help="seed of the random effects (default: 0)")
    apply.add_argument("--p", type=probability, default=1.0, help="probability of degrading each image (default: 1)")
    apply.add_argument("--device", default="cpu", help="torch device to run on (default: cpu)")
    apply.add_argument(
        "--overwrite",
        action="store_true",
        help="allow an output folder inside the input folder (its images are then not read as inputs); no option "
        "writes over an input image",
    )
    add_threads(apply)


def run(args: argparse.Namespace) -> int:
    from camdegrade._support.files import check_outputs_spare_inputs
    from camdegrade.io import read_image, write_image
    from camdegrade.transform import CameraDegrade

    degrade = CameraDegrade(args.profile, p=args.p, seed=args.seed)
    jobs = _jobs(args.input, args.output, args.overwrite)
    check_outputs_spare_inputs(jobs)
    batch = args.input.is_dir()
    failed: list[tuple[Path, str]] = []
    for source, target in jobs:
        try:
            image = read_image(source)
            write_image(degrade(image.to(args.device)).cpu(), target)
        except OSError as error:  # unreadable, truncated, too large, animated, unwritable: listed at the end
            if not batch:
                raise
            failed.append((source, str(error)))
            continue
        print(f"{printable(source)} -> {printable(target)}")
    name = printable(degrade.profile.name) if degrade.profile.name else repr(args.profile)
    print(f"degraded {len(jobs) - len(failed)} image(s) with profile {name}")
    if failed:
        list_failures(failed)
        raise BatchError(f"{len(failed)} of {len(jobs)} image(s) could not be degraded (listed above)", failed, [])
    return 0


def _jobs(source: Path, output: Path, overwrite: bool) -> list[tuple[Path, Path]]:
    """``(input image, output path)`` for ``apply``; refuses outputs that would replace or re-read inputs."""
    from camdegrade.io import input_images

    if source.is_file():
        return [(source, output / source.name if output.is_dir() else output)]
    found = input_images(source, output, overwrite=overwrite, output_name="output folder", allow="pass --overwrite")
    return [(path, output / relative) for path, relative in found]
