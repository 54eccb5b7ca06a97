"""``camdegrade info PROFILE`` and ``camdegrade list``: what a profile file says about itself, read without torch
(:mod:`camdegrade._profile_format.summary`): a short summary for people, or with ``--json`` the full record. Names and
descriptions come from files, so every one is shown escaped (:func:`~camdegrade._support.text.printable`; JSON escapes
its own): no profile can clear the screen or forge a line of the output."""

from __future__ import annotations

import argparse
import json
import sys

from camdegrade._support.text import printable
from camdegrade.cli._common import add_profile

__all__ = ["add_parsers", "run_info", "run_list"]


def add_parsers(commands: argparse._SubParsersAction) -> None:
    info = commands.add_parser(
        "info", help="summarize a profile: its chain, network, held-out quality and warnings (--json: everything)"
    )
    add_profile(info, "built-in profile name or .safetensors path")
    info.add_argument(
        "--json", action="store_true", help="print the full record as JSON: the metadata, effect values and versions"
    )
    commands.add_parser("list", help="list the built-in profiles")


def run_info(args: argparse.Namespace) -> int:
    from camdegrade._profile_format.header import read_header
    from camdegrade._profile_format.summary import profile_record, profile_summary

    if args.json:
        print(json.dumps(profile_record(args.profile), indent=1, sort_keys=True))
    else:
        print(profile_summary(args.profile))
        print("(--json prints the full record: the metadata, every effect value, the versions)")
    for warning in read_header(args.profile).version_warnings():
        print(f"camdegrade info: warning: {printable(warning)}", file=sys.stderr)
    return 0


def run_list(args: argparse.Namespace) -> int:
    from camdegrade._profile_format.header import list_profiles, read_header

    for name in list_profiles():
        print(f"{printable(name):24s} {printable(read_header(name).description)}")
    return 0
