"""The recipe options of ``fit`` and ``distill``, derived from the recipe fields
(:data:`camdegrade._support.recipes.FIELDS`: each a :class:`~camdegrade.fitting.FitConfig` field, an option of a fit
step such as ``--effects`` and ``--sensor-scale``, or ``--texture``, which says whether some steps run): each field's
option, type, help and the default it shows come from there, so a new recipe field cannot be forgotten here. Left out,
an option keeps the recipe's value; given, ``FitConfig.replace`` puts it where the table says."""

from __future__ import annotations

import argparse
from collections.abc import Callable, Mapping
from typing import Any

from camdegrade._support.recipes import FIELDS, MIN_SENSOR_SCALE, RECIPES, recipe_default
from camdegrade.cli._common import non_negative_int, number, positive_int, positive_number, seed, share


def sensor_scale(text: str) -> str | float:
    """``auto`` or a sensor scale from :data:`~camdegrade._support.recipes.MIN_SENSOR_SCALE` to 1."""
    if text == "auto":
        return text
    try:
        value = number(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"must be auto or a number from {MIN_SENSOR_SCALE} to 1, got {text}") from None
    if not MIN_SENSOR_SCALE <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"must be auto or a number from {MIN_SENSOR_SCALE} to 1, got {text}")
    return value


_TYPES: dict[str, Callable[[str], Any]] = {
    "count": positive_int,
    "count0": non_negative_int,
    "number": positive_number,
    "fraction": share(True),
    "seed": seed,
    "sensor": sensor_scale,
}
RECIPE_HELP = (
    "fast (default): a cosine schedule that stops once the validation PSNR stops rising; paper: the paper's 100 "
    "epochs, lr 0.01 halved every 30 epochs. The options below change one value of it"
)


def add_recipe_options(
    parser: argparse.ArgumentParser,
    *,
    not_offered: Mapping[str, str] = {},
    defaults: Mapping[str, str] = {},
) -> None:
    """``--recipe`` and an option per recipe field, except those of ``not_offered`` (field → why); ``defaults``
    replaces the default a field's help shows where the command's differs from the recipes'."""
    parser.add_argument("--recipe", choices=tuple(RECIPES), default="fast", help=RECIPE_HELP)
    for field in FIELDS:
        if field.name in not_offered:
            continue
        shown = f"{field.help} ({defaults.get(field.name) or recipe_default(field.name)})"
        if field.kind == "choice":
            parser.add_argument(field.option, choices=field.choices, default=None, help=shown)
        elif field.kind == "names":
            parser.add_argument(field.option, nargs="*", metavar="NAME", default=None, help=shown)
        else:
            parser.add_argument(field.option, type=_TYPES[field.kind], default=None, help=shown)


def recipe_changes(args: argparse.Namespace) -> dict[str, Any]:
    """The recipe values given on the command line (``None``: not given)."""
    return {field.name: getattr(args, field.name) for field in FIELDS if getattr(args, field.name, None) is not None}


def check_schedule_options(args: argparse.Namespace, schedule: str) -> None:
    """``--lr-halving-epochs`` only where the learning rate is halved (a step schedule)."""
    if getattr(args, "lr_halving_epochs", None) is not None and schedule != "step":
        raise ValueError(
            f"--lr-halving-epochs applies to --recipe paper or --schedule step (a step schedule), not to the "
            f"{schedule} schedule of --recipe {args.recipe}"
        )
