"""Command line: ``camdegrade list|info|apply|simulate|fit|diagnose ...`` (also ``python -m camdegrade``).

The one CLI module: every subcommand's parser and runner is here. Heavy imports (torch, the package's layers) wait
until a subcommand runs, so ``--help`` answers at once. User errors print one line on stderr, never a traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from collections.abc import Callable, Iterator, Sequence
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
    _add_apply_parser(commands)
    info = commands.add_parser("info", help="show a profile's network, effect chain, fitting record and quality")
    info.add_argument("profile", help="built-in profile name or .safetensors path")
    commands.add_parser("list", help="list the built-in profiles")
    _add_fit_parser(commands)
    _add_simulate_parser(commands)
    _add_diagnose_parser(commands)
    return parser


def _add_threads(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")


def _add_apply_parser(commands: argparse._SubParsersAction) -> None:
    apply = commands.add_parser("apply", help="degrade an image file, or every image in a folder (recursively)")
    apply.add_argument("profile", help="built-in profile name (see 'camdegrade list') or .safetensors path")
    apply.add_argument("input", type=Path, help="image file or folder")
    apply.add_argument("output", type=Path, help="output file (for a file input) or folder (for a folder input)")
    apply.add_argument("--seed", type=int, default=0, help="seed of the random effects (default: 0)")
    apply.add_argument("--p", type=float, default=1.0, help="probability of degrading each image (default: 1)")
    apply.add_argument("--device", default="cpu", help="torch device to run on (default: cpu)")
    _add_threads(apply)


def _add_fit_parser(commands: argparse._SubParsersAction) -> None:
    fit = commands.add_parser(
        "fit",
        help="fit a profile from (clean, captured) pairs",
        description="Fit a camera profile. PAIRS: a folder with clean/ and captured/ (matching relative names), a "
        "CSV manifest with clean,captured columns, or a folder plus --clean-suffix/--captured-suffix. Under "
        "'torchrun --nproc_per_node N -m camdegrade fit ...' the fit runs data-parallel (gloo on CPU, NCCL on GPU). "
        "Recipe options left out keep the paper's values.",
    )
    fit.add_argument("pairs", type=Path, help="pairs folder or CSV manifest")
    fit.add_argument("-o", "--output", type=Path, required=True, help="profile to write (.safetensors)")
    fit.add_argument("--epochs", type=int, default=None, help="training epochs (default: 100)")
    fit.add_argument("--crop", type=int, default=None, help="training crop size, a multiple of 4 (default: 128)")
    fit.add_argument("--batch-size", type=int, default=None, help="crops per step (default: 32)")
    fit.add_argument("--lr", type=float, default=None, help="Adam learning rate (default: 0.01)")
    fit.add_argument(
        "--lr-halving-epochs", type=int, default=None, help="halve the learning rate every N epochs (default: 30)"
    )
    fit.add_argument("--crops-per-pair", type=int, default=None, help="random crops per pair per epoch (default: 8)")
    fit.add_argument("--seed", type=int, default=0)
    fit.add_argument("--val-fraction", type=float, default=0.15, help="share of scenes for validation")
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
    fit.add_argument("--checkpoint", type=Path, default=None, help="default: OUTPUT with .ckpt.safetensors")
    fit.add_argument("--resume", action="store_true", help="continue an interrupted fit from --checkpoint")
    fit.add_argument("--name", default=None, help="profile name (default: OUTPUT's stem)")
    fit.add_argument("--description", default="")
    fit.add_argument("--quiet", action="store_true", help="no progress bar")


def _add_simulate_parser(commands: argparse._SubParsersAction) -> None:
    simulate = commands.add_parser(
        "simulate",
        help="make a pairs folder (clean/, captured/) with a virtual camera preset",
    )
    simulate.add_argument("preset", help="virtual camera preset, e.g. lowcost-robot")
    simulate.add_argument("input", type=Path, help="clean image file or folder")
    simulate.add_argument("out_dir", type=Path, help="output folder; gets clean/ and captured/")
    simulate.add_argument("--seed", type=int, default=0)
    simulate.add_argument("--max-side", type=int, default=None, help="downsize clean images larger than this")
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
    diagnose.add_argument("--out-profile", type=Path, default=None, help="write the profile with the added effects")
    diagnose.add_argument("--seed", type=int, default=0, help="seeds the split, simulations and bootstrap")
    diagnose.add_argument("--real", type=Path, default=None, help="unpaired mode: a folder of real captures")
    diagnose.add_argument("--calibration-fraction", type=float, default=0.5, help="share of scenes for fitting")
    diagnose.add_argument("--max-pairs", type=int, default=None, help="use at most this many pairs")
    diagnose.add_argument("--candidates", nargs="+", default=None, help="effect names to try (default: all)")
    diagnose.add_argument("--clean-suffix", default=None)
    diagnose.add_argument("--captured-suffix", default=None)
    _add_threads(diagnose)
    diagnose.add_argument("--quiet", action="store_true", help="print only the verdict")


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


def _run_fit(args: argparse.Namespace) -> int:
    import torch.distributed

    from camdegrade._distributed import is_main_process
    from camdegrade.fitting.fit import DEFAULT_EFFECTS, fit_profile, init_distributed_from_env
    from camdegrade.fitting.training import FitInterrupted

    if args.output.suffix != ".safetensors":
        raise ValueError(f"--output must end in .safetensors, got {str(args.output)!r}")
    checkpoint = args.checkpoint or args.output.with_name(args.output.stem + ".ckpt.safetensors")
    device = init_distributed_from_env(args.device)
    main_process = is_main_process()
    try:
        profile = fit_profile(
            args.pairs,
            epochs=args.epochs,
            crop=args.crop,
            batch_size=args.batch_size,
            lr=args.lr,
            lr_halving_epochs=args.lr_halving_epochs,
            crops_per_pair=args.crops_per_pair,
            seed=args.seed,
            val_fraction=args.val_fraction,
            align=args.align,
            clean_suffix=args.clean_suffix,
            captured_suffix=args.captured_suffix,
            strict=args.strict,
            size_mismatch=args.size_mismatch,
            effects=() if args.no_effects else DEFAULT_EFFECTS,
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
        if torch.distributed.is_available() and torch.distributed.is_initialized():
            torch.distributed.destroy_process_group()
    if main_process:
        profile.save(args.output)
        checkpoint.unlink(missing_ok=True)
        print(profile.describe())
        print(f"wrote {args.output}")
    return 0


def _run_simulate(args: argparse.Namespace) -> int:
    from camdegrade.sim import simulate_pairs

    written = simulate_pairs(args.preset, args.input, args.out_dir, seed=args.seed, max_side=args.max_side)
    print(f"wrote {len(written)} pair(s) to {args.out_dir} (clean/, captured/) with preset {args.preset!r}")
    return 0


def _run_diagnose(args: argparse.Namespace) -> int:
    from camdegrade.diagnose import diagnose
    from camdegrade.diagnose.unpaired import diagnose_unpaired

    if args.out_profile is not None and args.out_profile.suffix != ".safetensors":
        raise ValueError(f"--out-profile must end in .safetensors, got {str(args.out_profile)!r}")
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


_COMMANDS: dict[str, Callable[[argparse.Namespace], int]] = {
    "apply": _run_apply,
    "info": _run_info,
    "list": _run_list,
    "fit": _run_fit,
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
    parser = main_parser(prog)
    args = parser.parse_args(cli_args)
    if getattr(args, "device", None) is not None:
        _check_device(parser, args.device)
    try:
        with _threads(getattr(args, "threads", None)):
            return _COMMANDS[args.command](args)
    except (CamdegradeError, OSError, ValueError) as error:
        print(f"{parser.prog}: error: {error}", file=sys.stderr)
        return 1


def entrypoint() -> None:
    sys.exit(main())


if __name__ == "__main__":
    sys.exit(main(prog="python -m camdegrade"))
