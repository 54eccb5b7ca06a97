"""What every command shares: the parser class and argument types (checked while parsing, status 2), the threads
option, output checks before any work, the end-of-batch lists, and how a user error is printed (one line).

Nothing here imports torch at module level: ``--help``, ``--version``, ``list`` and ``info`` never import it.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import sys
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import NoReturn

from camdegrade._support.checks import check_seed
from camdegrade._support.text import printable, printable_lines
from camdegrade.errors import BatchError


class Parser(argparse.ArgumentParser):
    """argparse with one-line usage errors (status 2), like every other user error of the CLI."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {printable(message)} (see '{self.prog} --help')\n")


def whole_number(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer, got {text!r}") from None


def positive_int(text: str) -> int:
    value = whole_number(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1, got {value}")
    return value


def non_negative_int(text: str) -> int:
    value = whole_number(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be an integer >= 0, got {value}")
    return value


def seed(text: str) -> int:
    if text.strip().lstrip("+-").isdigit() and len(text.strip()) > 25:  # Python refuses to parse > 4300 digits
        shown = text.strip() if len(text.strip()) <= 40 else f"{text.strip()[:20]}... ({len(text.strip())} digits)"
        raise argparse.ArgumentTypeError(f"must be an integer from -2**63 to 2**64 - 1, got {shown}")
    try:
        return check_seed(whole_number(text))
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer from -2**63 to 2**64 - 1, got {text}") from None


def number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text}")
    return value


def probability(text: str) -> float:
    value = number(text)
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"must be a probability from 0 to 1, got {text}")
    return value


def positive_number(text: str) -> float:
    value = number(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be a number > 0, got {text}")
    return value


def share(low_inclusive: bool) -> Callable[[str], float]:
    """A fraction in [0, 1) or (0, 1)."""

    def fraction(text: str) -> float:
        value = number(text)
        if not (0.0 <= value < 1.0 if low_inclusive else 0.0 < value < 1.0):
            bounds = "from 0 (inclusive) to 1 (exclusive)" if low_inclusive else "between 0 and 1 (exclusive)"
            raise argparse.ArgumentTypeError(f"must be a fraction {bounds}, got {text}")
        return value

    return fraction


def profile_name(text: str) -> str:
    """A built-in profile name or a path: anything but the empty text (which would name the current folder)."""
    if not text.strip():
        raise argparse.ArgumentTypeError(
            f"empty profile name (got {text!r}); give a built-in name or a .safetensors path"
        )
    return text


def add_profile(parser: argparse.ArgumentParser, help_text: str) -> None:
    parser.add_argument("profile", type=profile_name, help=help_text)


def add_threads(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--threads", type=_thread_count, default=None, help="torch CPU threads (default: torch's choice)"
    )


def _thread_count(text: str) -> int:
    from camdegrade._runtime.threads import MAX_THREADS

    value = positive_int(text)
    if value > MAX_THREADS:
        raise argparse.ArgumentTypeError(f"must be an integer from 1 to {MAX_THREADS}, got {value}")
    return value


@contextlib.contextmanager
def threads(count: int | None) -> Iterator[None]:
    """Every command's ``--threads``: torch's CPU thread count for the command, restored afterwards."""
    if count is None:
        yield
        return
    from camdegrade._runtime.threads import torch_threads

    with torch_threads(count):
        yield


def check_outputs(outputs: dict[str, Path | None], inputs: Sequence[Path]) -> None:
    """Before any work: no output is an input file, no two outputs are one file, and each can be written."""
    from camdegrade._support.files import check_outputs_spare_inputs, check_writable, same_file

    given = {option: path for option, path in outputs.items() if path is not None}
    check_outputs_spare_inputs([(source, path) for source in inputs for path in given.values()])
    options = list(given)
    for index, first in enumerate(options):
        for second in options[index + 1 :]:
            if same_file(given[first], given[second]):
                raise ValueError(f"{first} and {second} name the same file ({str(given[first])!r}); give each its own")
    for path in given.values():
        check_writable(path)


def check_suffix(option: str, path: Path | None) -> None:
    if path is not None and path.suffix != ".safetensors":
        raise ValueError(f"{option} must end in .safetensors, got {str(path)!r}")


def image_files(folder: Path | None) -> list[Path]:
    from camdegrade.io import iter_images

    return list(iter_images(folder)) if folder is not None and folder.is_dir() else []


def list_failures(failed: Sequence[tuple[Path, str]]) -> None:
    """The end-of-batch summary (stdout): every file that could not be processed, with the reason."""
    print(f"{len(failed)} file(s) could not be read or written and were skipped:")
    for path, reason in failed:
        print(f"  {printable(path)}: {printable(reason)}")


def fail_on_unreadable(unreadable: Sequence[dict[str, str]], outcome: str) -> None:
    """After a run over pairs: list the files that could not be read and end with status 1 (the outputs stand)."""
    if unreadable:
        failed = [(Path(entry["path"]), entry["reason"]) for entry in unreadable]
        list_failures(failed)
        raise BatchError(
            f"{len(failed)} file(s) could not be read and were skipped; {outcome} (listed above)", failed, []
        )


def say(message: object) -> None:
    """A progress line of a command (names in it escaped, its own line breaks kept)."""
    print(printable_lines(message))


def print_error(prog: str, error: BaseException) -> None:
    """One line on stderr; a longer message (a pair report) sends its details to stdout first."""
    first, _, details = str(error).partition("\n")
    if details:
        print(printable_lines(details))
    print(f"{prog}: error: {printable(first)}", file=sys.stderr)
