"""``camdegrade info PROFILE`` and ``camdegrade list``: what a profile file says about itself, read without torch
(:mod:`camdegrade._profile_format.header`). Names and descriptions come from files, so every one is shown escaped
(:func:`~camdegrade._text.printable`): no profile can clear the screen or forge a line of the output."""

from __future__ import annotations

import argparse
import dataclasses
import sys

from camdegrade._text import printable
from camdegrade.cli._common import add_profile
from camdegrade.cli._quality import quality_lines


def add_parsers(commands: argparse._SubParsersAction) -> None:
    info = commands.add_parser("info", help="show a profile's network, effect chain, fitting record and quality")
    add_profile(info, "built-in profile name or .safetensors path")
    commands.add_parser("list", help="list the built-in profiles")


def run_info(args: argparse.Namespace) -> int:
    from camdegrade._profile_format.header import read_header

    header = read_header(args.profile)  # no torch: the metadata and a few small tensors
    print(_escaped(header).describe())
    quality = header.metadata.get("quality")
    for line in quality_lines(quality if isinstance(quality, dict) else {}):
        print(line)
    for warning in header.version_warnings():
        print(f"camdegrade info: warning: {printable(warning)}", file=sys.stderr)
    return 0


def run_list(args: argparse.Namespace) -> int:
    from camdegrade._profile_format.header import list_profiles, read_header

    for name in list_profiles():
        print(f"{printable(name):24s} {printable(read_header(name).description)}")
    return 0


def _escaped(header):
    """The header with its text values (name, description, versions) escaped; ``describe`` writes the structured
    values (fitted record, quality, effect configs) as JSON or ``repr``, which escape theirs."""
    metadata = {key: printable(value) if isinstance(value, str) else value for key, value in header.metadata.items()}
    return dataclasses.replace(header, metadata=metadata)
