"""Command line: ``camdegrade list|info|apply|simulate|fit|distill|diagnose ...`` (also ``python -m camdegrade``).

One module per command (``add_parser`` and ``run``); this one builds the parser and runs a command. Heavy imports
(torch, the package's layers) wait until a command needs them: ``--help``, ``--version``, ``list`` and ``info``
never import torch. User errors print one line on stderr, never a traceback: exit status 2 for a bad argument
(checked while parsing, before any work), 1 for everything else. Batches (a folder for ``apply`` or ``simulate``)
process every readable file and list the others at the end, with status 1. Names that come from files are printed
escaped (:func:`camdegrade._support.text.printable`). A reader that stops reading (``camdegrade list | head -1``) ends
the command quietly, with status 0.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
from collections.abc import Callable, Sequence

from camdegrade._version import __version__
from camdegrade.cli import apply, diagnose, distill, fit, info, simulate
from camdegrade.cli._common import Parser, print_error, threads
from camdegrade.errors import CamdegradeError

__all__ = ["entrypoint", "main", "main_parser"]

_COMMANDS: dict[str, Callable[[argparse.Namespace], int]] = {
    "apply": apply.run,
    "info": info.run_info,
    "list": info.run_list,
    "fit": fit.run,
    "distill": distill.run,
    "simulate": simulate.run,
    "diagnose": diagnose.run,
}


def main_parser(prog: str | None = None) -> argparse.ArgumentParser:
    parser = Parser(prog=prog, description="Make clean images look as if a specific camera had captured them.")
    parser.add_argument("--version", action="version", version=f"camdegrade {__version__}")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    apply.add_parser(commands)
    info.add_parsers(commands)
    fit.add_parser(commands)
    distill.add_parser(commands)
    simulate.add_parser(commands)
    diagnose.add_parser(commands)
    return parser


def main(cli_args: Sequence[str] | None = None, prog: str | None = None) -> int:
    """Run the CLI with ``cli_args`` (default: ``sys.argv[1:]``); return the exit status."""
    _tolerant_output()
    _sleeping_openmp_threads()
    parser = main_parser(prog)
    args = parser.parse_args(cli_args)
    try:
        if getattr(args, "device", None) is not None:
            from camdegrade._runtime.device import check_device

            try:
                check_device(args.device, "--device")
            except ValueError as error:
                parser.error(str(error))
        with threads(getattr(args, "threads", None)):
            return _COMMANDS[args.command](args)
    except BrokenPipeError as error:
        if not _stdout_closed():  # another pipe (a file argument, a process group): an error like any other
            print_error(parser.prog, error)
            return 1
        return 0  # `camdegrade info ... | head`: the reader has what it wanted
    except (CamdegradeError, OSError, ValueError) as error:
        print_error(parser.prog, error)
        return 1
    except KeyboardInterrupt:  # Ctrl-C: what was written is whole (every write is atomic)
        print(f"{parser.prog}: interrupted", file=sys.stderr)
        return 130


def _sleeping_openmp_threads() -> None:
    """Torch's OpenMP threads sleep while they wait, unless ``OMP_WAIT_POLICY`` says otherwise. Threads that spin
    wait for each other's time slices on a machine other processes share: there the diagnosis' held-out baseline
    took 75 s with 2 spinning threads and 1.4 s with 2 sleeping ones (docs/performance.md, *The diagnosis*). OpenMP
    reads the policy when torch loads, so it is set only before that."""
    if "torch" not in sys.modules:
        os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


def _stdout_closed() -> bool:
    """Whether the reader of stdout went away; if so, stdout is pointed at the null device, so that Python's own
    flush at exit has nowhere to fail. A pipe whose reader closed reports an error when polled; a write that
    failed may have dropped its buffer, so a flush alone cannot tell."""
    if not _reader_gone():
        return False
    with contextlib.suppress(OSError, ValueError, AttributeError):
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return True


def _reader_gone() -> bool:
    try:
        fileno = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # a replaced stream (tests): only its flush can tell
        try:
            sys.stdout.flush()
        except BrokenPipeError:
            return True
        return False
    import select

    if hasattr(select, "poll"):
        poller = select.poll()
        poller.register(fileno, select.POLLOUT)
        return any(events & select.POLLERR for _, events in poller.poll(0))
    try:
        sys.stdout.flush()
    except BrokenPipeError:
        return True
    return False


def _tolerant_output() -> None:
    """File names that are not valid UTF-8 reach stdout and stderr escaped instead of stopping a batch."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(AttributeError, ValueError):  # a replaced stream (tests) may not reconfigure
            stream.reconfigure(errors="backslashreplace")


def entrypoint() -> None:
    sys.exit(main())
