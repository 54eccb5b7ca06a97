"""Command line: ``camdegrade list|info|apply|simulate|fit|distill|diagnose ...`` (also ``python -m camdegrade``).

The one CLI module: every subcommand's parser and runner is here. Heavy imports (torch, the package's layers) wait
until a subcommand needs them: ``--help``, ``--version``, ``list`` and ``info`` never import torch. User errors
print one line on stderr, never a traceback: exit status 2 for a bad argument (checked while parsing, before any
work), 1 for everything else. Batches (a folder for ``apply`` or ``simulate``) process every readable file and list
the others at the end, with status 1.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import sys
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import NoReturn

from camdegrade._checks import check_seed
from camdegrade._recipes import PAPER, RECIPES, recipe_default
from camdegrade._version import __version__
from camdegrade.errors import BatchError, CamdegradeError


class _Parser(argparse.ArgumentParser):
    """argparse with one-line usage errors (status 2), like every other user error of the CLI."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


def _whole_number(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer, got {text!r}") from None


def _positive_int(text: str) -> int:
    value = _whole_number(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1, got {value}")
    return value


def _non_negative_int(text: str) -> int:
    value = _whole_number(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be an integer >= 0, got {value}")
    return value


def _seed(text: str) -> int:
    if text.strip().lstrip("+-").isdigit() and len(text.strip()) > 25:  # Python refuses to parse > 4300 digits
        shown = text.strip() if len(text.strip()) <= 40 else f"{text.strip()[:20]}... ({len(text.strip())} digits)"
        raise argparse.ArgumentTypeError(f"must be an integer from -2**63 to 2**64 - 1, got {shown}")
    try:
        return check_seed(_whole_number(text))
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer from -2**63 to 2**64 - 1, got {text}") from None


def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text}")
    return value


def _probability(text: str) -> float:
    value = _number(text)
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"must be a probability from 0 to 1, got {text}")
    return value


def _positive_number(text: str) -> float:
    value = _number(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be a number > 0, got {text}")
    return value


def _share(low_inclusive: bool) -> Callable[[str], float]:
    """A fraction in [0, 1) or (0, 1)."""

    def share(text: str) -> float:
        value = _number(text)
        if not (0.0 <= value < 1.0 if low_inclusive else 0.0 < value < 1.0):
            bounds = "from 0 (inclusive) to 1 (exclusive)" if low_inclusive else "between 0 and 1 (exclusive)"
            raise argparse.ArgumentTypeError(f"must be a fraction {bounds}, got {text}")
        return value

    return share


def main_parser(prog: str | None = None) -> argparse.ArgumentParser:
    parser = _Parser(
        prog=prog,
        description="Make clean images look as if a specific camera had captured them.",
    )
    parser.add_argument("--version", action="version", version=f"camdegrade {__version__}")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    _add_apply_parser(commands)
    info = commands.add_parser("info", help="show a profile's network, effect chain, fitting record and quality")
    info.add_argument("profile", help="built-in profile name or .safetensors path")
    commands.add_parser("list", help="list the built-in profiles")
    _add_fit_parser(commands)
    _add_distill_parser(commands)
    _add_simulate_parser(commands)
    _add_diagnose_parser(commands)
    return parser


def _thread_count(text: str) -> int:
    from camdegrade._threads import MAX_THREADS

    value = _positive_int(text)
    if value > MAX_THREADS:
        raise argparse.ArgumentTypeError(f"must be an integer from 1 to {MAX_THREADS}, got {value}")
    return value


def _add_threads(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--threads", type=_thread_count, default=None, help="torch CPU threads (default: torch's choice)"
    )


def _add_apply_parser(commands: argparse._SubParsersAction) -> None:
    apply = commands.add_parser("apply", help="degrade an image file, or every image in a folder (recursively)")
    apply.add_argument("profile", help="built-in profile name (see 'camdegrade list') or .safetensors path")
    apply.add_argument("input", type=Path, help="image file or folder")
    apply.add_argument("output", type=Path, help="output file (for a file input) or folder (for a folder input)")
    apply.add_argument("--seed", type=_seed, default=0, help="seed of the random effects (default: 0)")
    apply.add_argument("--p", type=_probability, default=1.0, help="probability of degrading each image (default: 1)")
    apply.add_argument("--device", default="cpu", help="torch device to run on (default: cpu)")
    apply.add_argument(
        "--overwrite",
        action="store_true",
        help="allow an output folder inside the input folder (its images are then not read as inputs); no option "
        "writes over an input image",
    )
    _add_threads(apply)


def _add_fit_parser(commands: argparse._SubParsersAction) -> None:
    fit = commands.add_parser(
        "fit",
        help="fit a profile from (clean, captured) pairs",
        description="Fit a camera profile. PAIRS: a folder with clean/ and captured/ (matching relative names), a "
        "CSV manifest with clean,captured columns, or a folder plus --clean-suffix/--captured-suffix. Under "
        "'torchrun --nproc_per_node N -m camdegrade fit ...' the fit runs data-parallel (gloo on CPU, NCCL on GPU). "
        "Recipe options left out keep the recipe's values.",
    )
    fit.add_argument("pairs", type=Path, help="pairs folder or CSV manifest")
    fit.add_argument("-o", "--output", type=Path, required=True, help="profile to write (.safetensors)")
    fit.add_argument(
        "--recipe",
        choices=tuple(RECIPES),
        default="fast",
        help="fast (default): a cosine schedule that stops once the validation PSNR stops rising; paper: the "
        "paper's 100 epochs, lr 0.01 halved every 30 epochs. The options below change one value of it",
    )
    fit.add_argument("--epochs", type=_positive_int, default=None, help=f"most epochs ({recipe_default('epochs')})")
    fit.add_argument(
        "--crop",
        type=_positive_int,
        default=None,
        help=f"training crop size, a multiple of 4 ({recipe_default('crop')})",
    )
    fit.add_argument(
        "--batch-size", type=_positive_int, default=None, help=f"crops per step ({recipe_default('batch_size')})"
    )
    fit.add_argument(
        "--lr", type=_positive_number, default=None, help=f"Adam learning rate at the start ({recipe_default('lr')})"
    )
    fit.add_argument(
        "--lr-halving-epochs",
        type=_positive_int,
        default=None,
        help=f"with --recipe paper: halve the learning rate every N epochs ({PAPER['lr_halving_epochs']})",
    )
    fit.add_argument(
        "--crops-per-pair",
        type=_positive_int,
        default=None,
        help=f"random crops per pair per epoch ({recipe_default('crops_per_pair')})",
    )
    fit.add_argument(
        "--patience",
        type=_non_negative_int,
        default=None,
        help=f"stop after N epochs without a better validation PSNR, 0 never ({recipe_default('patience')})",
    )
    fit.add_argument(
        "--width",
        type=_positive_int,
        default=None,
        help=f"network width ({recipe_default('width')}; 32 runs about 4x cheaper, see 'camdegrade distill')",
    )
    fit.add_argument("--seed", type=_seed, default=0)
    fit.add_argument("--val-fraction", type=_share(True), default=0.15, help="share of scenes for validation")
    fit.add_argument("--device", default="cpu")
    _add_threads(fit)
    fit.add_argument("--clean-suffix", default=None, help="e.g. _mean (with --captured-suffix)")
    fit.add_argument("--captured-suffix", default=None, help="e.g. _real, or _copy for the paper's layout")
    fit.add_argument("--strict", action="store_true", help="fail on any unmatched, unreadable or tiny file")
    fit.add_argument("--align", action="store_true", help="register each pair (sub-pixel shift) before training")
    fit.add_argument(
        "--size-mismatch",
        choices=("skip", "crop"),
        default="skip",
        help="pairs whose images differ in size: skip them (default) or centre-crop both to the common size",
    )
    fit.add_argument("--no-effects", action="store_true", help="network only: fit no effect stages after it")
    fit.add_argument(
        "--init-from",
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


def _add_distill_parser(commands: argparse._SubParsersAction) -> None:
    distill = commands.add_parser(
        "distill",
        help="make a faster profile: a narrower network trained to give what PROFILE's network gives (no pairs)",
        description="Distil PROFILE's network into one of --width (32: about a quarter of the arithmetic), trained "
        "on clean images to give what PROFILE's network gives; the effect stages are copied. No captures are "
        "needed: --images takes clean images like those the profile will degrade (best: your training set), "
        "and without it generated dead-leaves images are used.",
    )
    distill.add_argument("profile", help="built-in profile name or .safetensors path (the teacher)")
    distill.add_argument("-o", "--output", type=Path, required=True, help="profile to write (.safetensors)")
    distill.add_argument("--images", type=Path, default=None, help="folder of clean images (default: generated)")
    distill.add_argument("--width", type=_positive_int, default=32, help="the new network's width (default: 32)")
    distill.add_argument("--recipe", choices=tuple(RECIPES), default="fast", help="training recipe (default: fast)")
    distill.add_argument("--epochs", type=_positive_int, default=None, help=f"most epochs ({recipe_default('epochs')})")
    distill.add_argument("--seed", type=_seed, default=0)
    distill.add_argument("--device", default="cpu")
    distill.add_argument("--name", default=None, help="profile name (default: the teacher's name + '-fast')")
    distill.add_argument("--quiet", action="store_true", help="no progress bar")
    _add_threads(distill)


def _add_simulate_parser(commands: argparse._SubParsersAction) -> None:
    simulate = commands.add_parser(
        "simulate",
        help="make a pairs folder (clean/, captured/) with a virtual camera preset",
    )
    simulate.add_argument("preset", help="virtual camera preset, e.g. lowcost-robot")
    simulate.add_argument("input", type=Path, help="clean image file or folder")
    simulate.add_argument("out_dir", type=Path, help="output folder; gets clean/ and captured/")
    simulate.add_argument("--seed", type=_seed, default=0)
    simulate.add_argument("--max-side", type=_positive_int, default=None, help="downsize clean images larger than this")
    simulate.add_argument(
        "--overwrite",
        action="store_true",
        help="allow OUT_DIR inside the input folder (it is then not read as input); no option writes over an input",
    )
    _add_threads(simulate)


def _add_diagnose_parser(commands: argparse._SubParsersAction) -> None:
    diagnose = commands.add_parser(
        "diagnose",
        help="find where a profile's simulations differ from REAL captures, and which effect closes the gap",
        description="Diagnose the sim-to-real gap of PROFILE on REAL (clean, captured) PAIRS it was not fitted on "
        "(a folder with clean/ and captured/, a CSV manifest, or a folder plus --clean-suffix/--captured-suffix). "
        "The pairs are split by scene into a calibration part (candidate effects are fitted on it) and a held-out "
        "part (every gap is measured on it). With --real, PAIRS is a folder of clean images and --real a folder of "
        "captures of other scenes (unpaired: the distribution-level part only).",
    )
    diagnose.add_argument("profile", help="built-in profile name or .safetensors path")
    diagnose.add_argument("pairs", type=Path, help="pairs folder or CSV manifest (with --real: clean images folder)")
    diagnose.add_argument("--json", type=Path, default=None, help="write the JSON report here")
    diagnose.add_argument("--html", type=Path, default=None, help="write the one-file HTML report here")
    diagnose.add_argument("--out-profile", type=Path, default=None, help="write the profile with the accepted changes")
    diagnose.add_argument("--seed", type=_seed, default=0, help="seeds the split, simulations and bootstrap")
    diagnose.add_argument("--real", type=Path, default=None, help="unpaired mode: a folder of real captures")
    diagnose.add_argument("--calibration-fraction", type=_share(False), default=0.5, help="share of scenes for fitting")
    diagnose.add_argument("--max-pairs", type=_positive_int, default=None, help="use at most this many pairs")
    diagnose.add_argument("--candidates", nargs="+", default=None, help="effect names to try adding (default: all)")
    diagnose.add_argument(
        "--kinds", nargs="+", default=None, help="kinds of change to try: add remove refit network (default: all)"
    )
    diagnose.add_argument("--no-critic", action="store_true", help="skip the learned critic (faster)")
    diagnose.add_argument("--clean-suffix", default=None)
    diagnose.add_argument("--captured-suffix", default=None)
    _add_threads(diagnose)
    diagnose.add_argument("--quiet", action="store_true", help="print only the verdict")


def _run_apply(args: argparse.Namespace) -> int:
    from camdegrade._files import check_outputs_spare_inputs
    from camdegrade.io import read_image, write_image
    from camdegrade.transform import CameraDegrade

    degrade = CameraDegrade(args.profile, p=args.p, seed=args.seed)
    jobs = _apply_jobs(args.input, args.output, args.overwrite)
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
        print(f"{source} -> {target}")
    print(f"degraded {len(jobs) - len(failed)} image(s) with profile {degrade.profile.name or args.profile!r}")
    if failed:
        _list_failures(failed)
        raise BatchError(f"{len(failed)} of {len(jobs)} image(s) could not be degraded (listed above)", failed, [])
    return 0


def _apply_jobs(source: Path, output: Path, overwrite: bool) -> list[tuple[Path, Path]]:
    """``(input image, output path)`` for ``apply``; refuses outputs that would replace or re-read inputs."""
    from camdegrade.io import input_images

    if source.is_file():
        return [(source, output / source.name if output.is_dir() else output)]
    found = input_images(source, output, overwrite=overwrite, output_name="output folder", allow="pass --overwrite")
    return [(path, output / relative) for path, relative in found]


def _list_failures(failed: Sequence[tuple[Path, str]]) -> None:
    """The end-of-batch summary (stdout): every file that could not be processed, with the reason."""
    print(f"{len(failed)} file(s) could not be read or written and were skipped:")
    for path, reason in failed:
        print(f"  {path}: {reason}")


def _run_info(args: argparse.Namespace) -> int:
    from camdegrade._metadata import read_header

    header = read_header(args.profile)  # no torch: the metadata and a few small tensors
    print(header.describe())
    for warning in header.version_warnings():
        print(f"camdegrade info: warning: {warning}", file=sys.stderr)
    return 0


def _run_list(args: argparse.Namespace) -> int:
    from camdegrade._metadata import list_profiles, read_header

    for name in list_profiles():
        print(f"{name:24s} {read_header(name).description}")
    return 0


def _run_fit(args: argparse.Namespace) -> int:
    import torch.distributed

    from camdegrade._distributed import is_distributed, is_main_process
    from camdegrade.fitting.fit import DEFAULT_EFFECTS, fit_profile, init_distributed_from_env
    from camdegrade.fitting.training import FitInterrupted

    if args.lr_halving_epochs is not None and RECIPES[args.recipe]["schedule"] != "step":
        raise ValueError(f"--lr-halving-epochs applies to --recipe paper (a step schedule), not to {args.recipe!r}")
    checkpoint = _fit_checkpoint(args)
    device = init_distributed_from_env(args.device)
    main_process = is_main_process()
    try:
        profile = fit_profile(
            args.pairs,
            recipe=args.recipe,
            epochs=args.epochs,
            crop=args.crop,
            batch_size=args.batch_size,
            lr=args.lr,
            lr_halving_epochs=args.lr_halving_epochs,
            crops_per_pair=args.crops_per_pair,
            patience=args.patience,
            width=args.width,
            seed=args.seed,
            val_fraction=args.val_fraction,
            align=args.align,
            clean_suffix=args.clean_suffix,
            captured_suffix=args.captured_suffix,
            strict=args.strict,
            size_mismatch=args.size_mismatch,
            effects=() if args.no_effects else DEFAULT_EFFECTS,
            init_from=args.init_from,
            device=device,
            checkpoint=checkpoint,
            resume=args.resume,
            progress=not args.quiet and main_process,
            name=args.name or args.output.stem,
            description=args.description,
            log=print if main_process else None,
        )
    except FitInterrupted as interrupted:
        print(f"camdegrade fit: {interrupted}; run again with --resume", file=sys.stderr)
        return 130
    finally:
        if is_distributed():
            torch.distributed.destroy_process_group()
    if main_process:
        profile.save(args.output)
        checkpoint.unlink(missing_ok=True)
        print(profile.describe())
        print(f"wrote {args.output}")
        _fail_on_unreadable(profile.fitted.get("unreadable", []), "the profile was fitted on the other pairs")
    return 0


def _fit_checkpoint(args: argparse.Namespace) -> Path:
    """The checkpoint path of ``fit``, after checking it and ``--output`` before training, not after it: writable,
    not one file, and neither of them a file of the pairs."""
    if args.output.suffix != ".safetensors":
        raise ValueError(f"--output must end in .safetensors, got {str(args.output)!r}")
    checkpoint = args.checkpoint or args.output.with_name(args.output.stem + ".ckpt.safetensors")
    if checkpoint.resolve() == args.output.resolve():
        raise ValueError(
            f"--checkpoint must differ from --output, got {str(checkpoint)!r} for both: the checkpoint is deleted "
            "after a successful fit, which would delete the profile"
        )
    _check_outputs({"--output": args.output, "--checkpoint": checkpoint}, _pair_files(args.pairs, args))
    if args.resume and not checkpoint.is_file():
        raise FileNotFoundError(
            f"--resume: checkpoint {str(checkpoint)!r} does not exist; check --checkpoint, or start a new fit "
            "without --resume"
        )
    return checkpoint


def _pair_files(pairs: Path, args: argparse.Namespace) -> list[Path]:
    """Every file a pairs source names (the manifest itself too), to keep outputs off them; none when the source
    cannot be read (the command then reports that)."""
    from camdegrade.errors import PairsError
    from camdegrade.fitting.pairs import discover_pairs

    try:
        report = discover_pairs(
            pairs, clean_suffix=args.clean_suffix, captured_suffix=args.captured_suffix, check_images=False
        )
    except (PairsError, OSError, ValueError):
        return [pairs] if pairs.is_file() else []
    files = [path for pair in report.pairs for path in (pair.clean, pair.captured)]
    return [*files, pairs] if pairs.is_file() else files


def _image_files(folder: Path | None) -> list[Path]:
    from camdegrade.io import iter_images

    return list(iter_images(folder)) if folder is not None and folder.is_dir() else []


def _check_outputs(outputs: dict[str, Path | None], inputs: Sequence[Path]) -> None:
    """Before any work: no output is an input file, no two outputs are one file, and each can be written."""
    from camdegrade._files import check_outputs_spare_inputs, check_writable, same_file

    given = {option: path for option, path in outputs.items() if path is not None}
    check_outputs_spare_inputs([(source, path) for source in inputs for path in given.values()])
    options = list(given)
    for index, first in enumerate(options):
        for second in options[index + 1 :]:
            if same_file(given[first], given[second]):
                raise ValueError(f"{first} and {second} name the same file ({str(given[first])!r}); give each its own")
    for path in given.values():
        check_writable(path)


def _fail_on_unreadable(unreadable: Sequence[dict[str, str]], outcome: str) -> None:
    """After a run over pairs: list the files that could not be read and end with status 1 (the outputs stand)."""
    if unreadable:
        failed = [(Path(entry["path"]), entry["reason"]) for entry in unreadable]
        _list_failures(failed)
        raise BatchError(
            f"{len(failed)} file(s) could not be read and were skipped; {outcome} (listed above)", failed, []
        )


def _run_simulate(args: argparse.Namespace) -> int:
    from camdegrade.sim import simulate_pairs

    options = {"seed": args.seed, "max_side": args.max_side, "overwrite": args.overwrite}
    try:
        written = simulate_pairs(args.preset, args.input, args.out_dir, **options)
    except BatchError as error:
        print(f"wrote {len(error.done)} pair(s) to {args.out_dir} (clean/, captured/) with preset {args.preset!r}")
        _list_failures(error.failed)
        raise BatchError(
            f"{len(error.failed)} of {len(error.failed) + len(error.done)} image(s) could not be simulated "
            "(listed above)",
            error.failed,
            error.done,
        ) from None
    print(f"wrote {len(written)} pair(s) to {args.out_dir} (clean/, captured/) with preset {args.preset!r}")
    return 0


def _run_diagnose(args: argparse.Namespace) -> int:
    from camdegrade.diagnose import diagnose
    from camdegrade.diagnose.unpaired import diagnose_unpaired
    from camdegrade.fitting.pairs import UNREADABLE
    from camdegrade.profile import resolve_profile_path

    if args.out_profile is not None and args.out_profile.suffix != ".safetensors":
        raise ValueError(f"--out-profile must end in .safetensors, got {str(args.out_profile)!r}")
    outputs = {"--json": args.json, "--html": args.html, "--out-profile": args.out_profile}
    inputs = [resolve_profile_path(args.profile), *_pair_files(args.pairs, args), *_image_files(args.real)]
    _check_outputs(outputs, inputs)
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
            kinds=args.kinds,
            critic=not args.no_critic,
            seed=args.seed,
            clean_suffix=args.clean_suffix,
            captured_suffix=args.captured_suffix,
            max_pairs=args.max_pairs,
            log=log,
        )
    if args.quiet:
        print(report.verdict)
        skipped = getattr(report, "skipped", [])
        if skipped:  # a dropped pair is never silent, even with --quiet
            print(f"{len(skipped)} file(s) skipped while loading the pairs (see the JSON report's 'skipped')")
    if args.json is not None:
        print(f"wrote {report.write_json(args.json)}")
    if args.html is not None:
        print(f"wrote {report.write_html(args.html)}")
    if args.out_profile is not None:
        if report.profile is None or not report.accepted:
            print("no change was accepted; --out-profile not written", file=sys.stderr)
        else:
            report.profile.save(args.out_profile)
            print(f"wrote {args.out_profile} ({', '.join(report.accepted)})")
    unreadable = [entry for entry in getattr(report, "skipped", []) if entry["reason"].startswith(UNREADABLE)]
    _fail_on_unreadable(unreadable, "the diagnosis used the other pairs")
    return 0


def _run_distill(args: argparse.Namespace) -> int:
    from camdegrade.fitting.distill import distill_profile
    from camdegrade.profile import resolve_profile_path

    if args.output.suffix != ".safetensors":
        raise ValueError(f"--output must end in .safetensors, got {str(args.output)!r}")
    _check_outputs({"--output": args.output}, [resolve_profile_path(args.profile), *_image_files(args.images)])
    profile = distill_profile(
        args.profile,
        args.images,
        width=args.width,
        recipe=args.recipe,
        epochs=args.epochs,
        seed=args.seed,
        device=args.device,
        progress=not args.quiet,
        name=args.name,
        log=print,
    )
    profile.save(args.output)
    print(profile.describe())
    print(f"wrote {args.output}")
    return 0


_COMMANDS: dict[str, Callable[[argparse.Namespace], int]] = {
    "apply": _run_apply,
    "info": _run_info,
    "list": _run_list,
    "fit": _run_fit,
    "distill": _run_distill,
    "simulate": _run_simulate,
    "diagnose": _run_diagnose,
}


def _check_device(parser: argparse.ArgumentParser, name: str) -> None:
    import torch

    try:
        device = torch.device(name)
    except (RuntimeError, ValueError):
        parser.error(f"--device must be a torch device such as 'cpu' or 'cuda:0', got {name!r}")
    if device.type == "cuda" and not torch.cuda.is_available():
        parser.error(f"--device {name!r} asks for CUDA, but no CUDA device is available here")
    if device.type == "meta":
        parser.error("--device 'meta' holds no data, so nothing can be computed on it; use 'cpu' or 'cuda'")
    try:
        torch.empty(1, device=device)
    except Exception as error:  # a backend that is not built in may raise anything (ImportError, ...)
        reason = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        parser.error(f"--device {name!r} cannot be used here ({reason})")


@contextlib.contextmanager
def _threads(threads: int | None) -> Iterator[None]:
    """Every command's ``--threads``: torch's CPU thread count for the command, restored afterwards."""
    if threads is None:
        yield
        return
    from camdegrade._threads import torch_threads

    with torch_threads(threads):
        yield


def main(cli_args: Sequence[str] | None = None, prog: str | None = None) -> int:
    """Run the CLI with ``cli_args`` (default: ``sys.argv[1:]``); return the exit status."""
    _tolerant_output()
    parser = main_parser(prog)
    args = parser.parse_args(cli_args)
    if getattr(args, "device", None) is not None:
        _check_device(parser, args.device)
    try:
        with _threads(getattr(args, "threads", None)):
            return _COMMANDS[args.command](args)
    except BrokenPipeError as error:
        if not _stdout_closed():  # another pipe (a file argument, a process group): an error like any other
            _print_error(parser.prog, error)
            return 1
        return 0  # `camdegrade info ... | head`: the reader has what it wanted
    except (CamdegradeError, OSError, ValueError) as error:
        _print_error(parser.prog, error)
        return 1
    except KeyboardInterrupt:  # Ctrl-C: what was written is whole (every write is atomic)
        print(f"{parser.prog}: interrupted", file=sys.stderr)
        return 130


def _print_error(prog: str, error: BaseException) -> None:
    """One line on stderr; a longer message (a pair report) sends its details to stdout first."""
    first, _, details = str(error).partition("\n")
    if details:
        print(details)
    print(f"{prog}: error: {first}", file=sys.stderr)


def _stdout_closed() -> bool:
    """Whether the reader of stdout went away; if so, stdout is pointed at the null device, so that Python's own
    flush at exit has nowhere to fail."""
    try:
        sys.stdout.flush()
    except BrokenPipeError:
        pass
    else:
        return False
    with contextlib.suppress(OSError, ValueError, AttributeError):
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return True


def _tolerant_output() -> None:
    """File names that are not valid UTF-8 reach stdout and stderr escaped instead of stopping a batch."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(AttributeError, ValueError):  # a replaced stream (tests) may not reconfigure
            stream.reconfigure(errors="backslashreplace")


def entrypoint() -> None:
    sys.exit(main())


if __name__ == "__main__":
    sys.exit(main(prog="python -m camdegrade"))
