"""``camdegrade fit PAIRS -o PROFILE``: fit a camera profile (:func:`~camdegrade.fitting.fit_profile`).

The pairs are discovered once; the outputs are checked against that report before any work, and the loaded pair
set is passed on. The recipe options are the recipe's fields (:mod:`camdegrade.cli._recipe`).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from camdegrade._profile_format.summary import quality_lines
from camdegrade._support.recipes import FIELDS
from camdegrade._support.text import printable
from camdegrade.cli._common import (
    add_threads,
    check_outputs,
    check_suffix,
    fail_on_unreadable,
    profile_name,
    say,
)
from camdegrade.cli._pairs import PAIRS_LAYOUTS, add_pair_options, discover, report_files
from camdegrade.cli._recipe import add_recipe_options, check_schedule_options, recipe_changes
from camdegrade.errors import CamdegradeError

__all__ = ["add_parser", "run"]

#: What ``fit --unpaired`` does with each of ``fit``'s options (by ``dest``; ``tests/test_unpaired_cli.py`` builds the
#: parser and holds every option to one of the two): passed on to :func:`~camdegrade.fitting.unpaired.fit_unpaired`
#: (``--max-pairs`` as ``max_images``, ``--threads`` by the command line for every command; ``--device``: the
#: unpaired fit runs on the CPU, another device is refused; ``--checkpoint``: written after each step, default
#: OUTPUT with ``.ckpt.safetensors``, removed once the profile is written) ...
UNPAIRED_USES: tuple[str, ...] = (
    "unpaired",
    "clean",
    "area_sensor",
    "output",
    "seed",
    "effects",
    "learned_texture",
    "sensor_scale",
    "max_pairs",
    "strict",
    "threads",
    "device",
    "name",
    "description",
    "quiet",
    "checkpoint",
    "resume",
)
_NO_NETWORK = "an unpaired profile has no network to train"
#: ... or refused by name when given, with the reason.
UNPAIRED_REFUSES: dict[str, str] = {
    "pairs": "give either PAIRS or --unpaired CAPTURED",
    "recipe": _NO_NETWORK,
    **{field.name: _NO_NETWORK for field in FIELDS if field.name not in UNPAIRED_USES},
    "val_fraction": "no pairs are held out: each stage is checked on random halves of the two sets",
    "texture": "the unpaired fit matches the captures' spectrum with its own stages (blur, sharpen, "
    "frequency_response: choose them with --effects)",
    "clean_suffix": "the unpaired fit reads two folders (CAPTURED and --clean), not pairs",
    "captured_suffix": "the unpaired fit reads two folders (CAPTURED and --clean), not pairs",
    "align": "there are no pairs to register",
    "jitter": "a displacement is read from the coherence of pairs",
    "size_mismatch": "there are no pairs to match: images of any sizes are read as they are",
    "init_from": _NO_NETWORK,
}
#: Option values that mean "not given" besides ``None`` (the parser's defaults).
_NOT_GIVEN: dict[str, object] = {"recipe": "fast", "size_mismatch": "skip", "align": False, "resume": False}


def add_parser(commands: argparse._SubParsersAction) -> None:
    fit = commands.add_parser(
        "fit",
        help="fit a profile from (clean, captured) pairs",
        description=f"Fit a camera profile. PAIRS: {PAIRS_LAYOUTS}. Under 'torchrun --nproc_per_node N -m "
        "camdegrade fit ...' the fit runs data-parallel (gloo on CPU, NCCL on GPU). Recipe options left out keep "
        "the recipe's values.",
    )
    fit.add_argument("pairs", type=Path, nargs="?", help="pairs folder or CSV manifest (not with --unpaired)")
    fit.add_argument(
        "--unpaired",
        type=Path,
        default=None,
        metavar="CAPTURED",
        help="fit an effects-only profile from a folder of the camera's own photos, no pairs "
        "(docs/fitting.md, 'Unpaired fitting'); with --clean, a folder of clean images of other scenes",
    )
    fit.add_argument("--clean", type=Path, default=None, metavar="CLEAN", help="clean images for --unpaired")
    fit.add_argument(
        "--area-sensor",
        action="store_true",
        help="--unpaired: also search a sensor that reads its pixels' areas where no upscale shows (off by default; "
        "docs/results.md, 'An area-sampling sensor in the unpaired fit')",
    )
    fit.add_argument("-o", "--output", type=Path, required=True, help="profile to write (.safetensors)")
    add_recipe_options(fit)
    fit.add_argument(
        "--no-effects", dest="effects", action="store_const", const=[], help="network only: --effects with no names"
    )
    fit.add_argument("--device", default="cpu")
    add_threads(fit)
    add_pair_options(fit, loading=True)
    fit.add_argument(
        "--init-from",
        type=profile_name,
        default=None,
        metavar="PROFILE",
        help="start the network from this profile's weights (built-in name or .safetensors path) instead of a fresh "
        "initialisation; a refit usually takes fewer epochs and a lower --lr (e.g. --epochs 20 --lr 0.001)",
    )
    fit.add_argument("--checkpoint", type=Path, default=None, help="default: OUTPUT with .ckpt.safetensors")
    fit.add_argument("--resume", action="store_true", help="continue an interrupted fit from --checkpoint")
    fit.add_argument("--name", default=None, help="profile name (default: OUTPUT's stem)")
    fit.add_argument("--description", default="")
    fit.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    import torch.distributed

    from camdegrade._runtime.distributed import is_distributed, is_main_process
    from camdegrade.fitting.fit import fit_profile, init_distributed_from_env
    from camdegrade.fitting.network.training import FitInterrupted
    from camdegrade.fitting.recipe import FitConfig
    from camdegrade.pairs.pairset import PairSet

    if (args.pairs is None) == (args.unpaired is None):
        raise ValueError("give either PAIRS or --unpaired CAPTURED, got " + ("both" if args.pairs else "neither"))
    if args.unpaired is not None:
        return _run_unpaired(args)
    if args.clean is not None:
        raise ValueError(f"--clean goes with --unpaired, got --clean {printable(args.clean)} and PAIRS")
    if args.area_sensor:
        raise ValueError("--area-sensor goes with --unpaired, got --area-sensor and PAIRS")
    recipe = FitConfig.recipe(args.recipe, **recipe_changes(args))
    check_schedule_options(args, recipe.schedule)
    checkpoint = _checkpoint(args)
    report = discover(args)
    check_outputs({"--output": args.output, "--checkpoint": checkpoint}, report_files(report, args.pairs))
    device = init_distributed_from_env(args.device)
    main_process = is_main_process()
    log = say if main_process else None
    try:
        pairs = PairSet.load(report, max_pairs=args.max_pairs, align=args.align, log=log)
        profile = fit_profile(
            pairs,
            recipe,
            init_from=args.init_from,
            device=device,
            checkpoint=checkpoint,
            resume=args.resume,
            progress=not args.quiet and main_process,
            name=args.name or args.output.stem,
            description=args.description,
            log=log,
        )
    except FitInterrupted as interrupted:
        print(f"camdegrade fit: {interrupted}; run again with --resume", file=sys.stderr)
        return 130
    finally:
        if is_distributed():
            torch.distributed.destroy_process_group()
    if main_process:
        _write(profile, args, checkpoint)
    return 0


def _unpaired_effects(effects: Sequence[str], learned: str | None) -> Sequence[str]:
    """``effects`` with the learned texture stage added (``--learned-texture critic``) or left out (``none``)."""
    from camdegrade.effects import LearnedTexture

    if learned is None:
        return effects
    names = [name for name in effects if name != LearnedTexture.name]
    return [*names, LearnedTexture.name] if learned == "critic" else names


def _run_unpaired(args: argparse.Namespace) -> int:
    """``fit --unpaired CAPTURED [--clean CLEAN]``: :func:`~camdegrade.fitting.unpaired.fit_unpaired`, written; the
    checkpoint it writes after each step removed once the profile is."""
    from camdegrade.errors import FitInterrupted
    from camdegrade.fitting.unpaired import UNPAIRED_EFFECTS, fit_unpaired

    refuse_unpaired_options(args)
    checkpoint = _checkpoint(args)
    check_suffix("--checkpoint", checkpoint)
    check_outputs({"--output": args.output, "--checkpoint": checkpoint}, [])
    try:
        profile = fit_unpaired(
            args.unpaired,
            args.clean,
            effects=_unpaired_effects(UNPAIRED_EFFECTS if args.effects is None else args.effects, args.learned_texture),
            seed=args.seed if args.seed is not None else 0,
            sensor_scale=args.sensor_scale if args.sensor_scale is not None else "auto",
            area_sensor=args.area_sensor,
            max_images=args.max_pairs,
            strict=args.strict,
            progress=not args.quiet,
            name=args.name or args.output.stem,
            description=args.description,
            log=say,
            checkpoint=checkpoint,
            resume=args.resume,
        )
    except FitInterrupted as interrupted:
        print(f"camdegrade fit: {interrupted}; run again with --resume", file=sys.stderr)
        return 130
    profile.save(args.output)
    checkpoint.unlink(missing_ok=True)
    say(profile.describe())
    print(f"wrote {printable(args.output)}")
    for warning in profile.fitted.get("warnings", []):
        print(f"camdegrade fit: warning: {warning}", file=sys.stderr)
    fail_on_unreadable(profile.fitted.get("unreadable", []), "the profile was fitted on the other images")
    return 0


def refuse_unpaired_options(args: argparse.Namespace) -> None:
    """A ``ValueError`` naming the first option given that ``fit --unpaired`` does not use (:data:`UNPAIRED_REFUSES`),
    ``--effects`` with no names (network only) and a ``--device`` other than the CPU."""
    for dest, why in UNPAIRED_REFUSES.items():
        value = getattr(args, dest, None)
        if dest != "pairs" and value is not None and value != _NOT_GIVEN.get(dest, False):
            option = "--" + dest.replace("_", "-")
            raise ValueError(f"{option} is not used with --unpaired ({why}), got {option} {printable(str(value))}")
    if args.effects == []:
        raise ValueError(
            f"--no-effects (or --effects with no names: network only) is not used with --unpaired ({_NO_NETWORK}); "
            "name the stages to fit with --effects"
        )
    if str(args.device).split(":")[0] != "cpu":
        raise ValueError(f"--device {printable(str(args.device))} is not used with --unpaired (it runs on the CPU)")


def _write(profile, args: argparse.Namespace, checkpoint: Path) -> None:
    """The profile written (unless ``--strict`` and a warning), its warnings on stderr, the unreadable files listed."""
    warnings = profile.fitted.get("warnings", [])
    if warnings and args.strict:
        raise CamdegradeError(f"{warnings[0]}; {args.output} not written (--strict)")
    profile.save(args.output)
    checkpoint.unlink(missing_ok=True)
    say(profile.describe())
    for line in quality_lines(profile.quality):
        say(line)
    print(f"wrote {printable(args.output)}")
    for warning in warnings:
        print(f"camdegrade fit: warning: {warning}", file=sys.stderr)
    _next_step(profile, args)
    fail_on_unreadable(profile.fitted.get("unreadable", []), "the profile was fitted on the other pairs")


def _next_step(profile, args: argparse.Namespace) -> None:
    """The exact diagnose command, quoted, when the fit's validation critic tells the profile from the captures."""
    from camdegrade.fitting.critic_warning import critic_tells, diagnose_command

    if args.pairs is not None and critic_tells(profile.quality.get("fidelity")):
        command = diagnose_command(str(args.output), str(args.pairs))
        print(f"camdegrade fit: to look for the cause: {printable(command)}", file=sys.stderr)


def _checkpoint(args: argparse.Namespace) -> Path:
    """The checkpoint path, after checking it and ``--output`` before any work: ``.safetensors``, not one file,
    and an existing checkpoint for ``--resume`` (kept off the pairs' files once they are discovered)."""
    check_suffix("--output", args.output)
    checkpoint = args.checkpoint or args.output.with_name(args.output.stem + ".ckpt.safetensors")
    if checkpoint.resolve() == args.output.resolve():
        raise ValueError(
            f"--checkpoint must differ from --output, got {str(checkpoint)!r} for both: the checkpoint is deleted "
            "after a successful fit, which would delete the profile"
        )
    if args.resume and not checkpoint.is_file():
        raise FileNotFoundError(
            f"--resume: checkpoint {str(checkpoint)!r} does not exist; check --checkpoint, or start a new fit "
            "without --resume"
        )
    return checkpoint
