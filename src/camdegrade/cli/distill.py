"""``camdegrade distill PROFILE -o FAST``: a narrower network trained to give what PROFILE's network gives
(:func:`~camdegrade.fitting.distill_profile`); the recipe options are the recipe's fields."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from camdegrade._support.text import printable
from camdegrade.cli._common import add_profile, add_threads, check_outputs, check_suffix, image_files, say
from camdegrade.cli._recipe import add_recipe_options, check_schedule_options, recipe_changes
from camdegrade.errors import CamdegradeError

__all__ = ["NOT_OFFERED", "STUDENT_WIDTH", "add_parser", "run"]

#: The student's width unless told (``camdegrade.fitting.network.distill.DEFAULT_WIDTH``, here without importing torch).
STUDENT_WIDTH = 32
#: Recipe fields distill does not offer, and why.
NOT_OFFERED = {"effects": "the teacher's effect stages are copied, none is fitted"}


def add_parser(commands: argparse._SubParsersAction) -> None:
    distill = commands.add_parser(
        "distill",
        help="make a faster profile: a narrower network trained to give what PROFILE's network gives (no pairs)",
        description="Distil PROFILE's network into one of --width (32: about a quarter of the arithmetic), trained "
        "on clean images to give what PROFILE's network gives; the effect stages are copied. No captures are "
        "needed: --images takes clean images like those the profile will degrade (best: your training set), "
        "and without it generated dead-leaves images are used. --val-fraction is the share of the images that "
        "validates.",
    )
    add_profile(distill, "built-in profile name or .safetensors path (the teacher)")
    distill.add_argument("-o", "--output", type=Path, required=True, help="profile to write (.safetensors)")
    distill.add_argument("--images", type=Path, default=None, help="folder of clean images (default: generated)")
    add_recipe_options(distill, not_offered=NOT_OFFERED, defaults={"width": f"distill: {STUDENT_WIDTH}"})
    distill.add_argument("--device", default="cpu")
    distill.add_argument("--name", default=None, help="profile name (default: the teacher's name + '-fast')")
    distill.add_argument(
        "--strict",
        action="store_true",
        help="write no profile whose student is further from its teacher than "
        "the clean images are (on the validation images)",
    )
    distill.add_argument("--quiet", action="store_true", help="no progress bar")
    add_threads(distill)


def run(args: argparse.Namespace) -> int:
    from camdegrade.fitting.network.distill import distill_profile
    from camdegrade.fitting.recipe import FitConfig
    from camdegrade.profile import resolve_profile_path

    recipe = FitConfig.recipe(args.recipe, **{"width": STUDENT_WIDTH, **recipe_changes(args)})
    check_schedule_options(args, recipe.schedule)
    check_suffix("--output", args.output)
    check_outputs({"--output": args.output}, [resolve_profile_path(args.profile), *image_files(args.images)])
    profile = distill_profile(
        args.profile, args.images, recipe=recipe, device=args.device, progress=not args.quiet, name=args.name, log=say
    )
    warnings = profile.fitted.get("warnings", [])
    if warnings and args.strict:
        raise CamdegradeError(f"{warnings[0]}; {args.output} not written (--strict)")
    profile.save(args.output)
    say(profile.describe())
    print(f"wrote {printable(args.output)}")
    for warning in warnings:
        print(f"camdegrade distill: warning: {warning}", file=sys.stderr)
    return 0
