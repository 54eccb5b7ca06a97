"""``python -m camdegrade``: the command line (:mod:`camdegrade.cli`)."""

import sys

from camdegrade.cli import entrypoint, main

__all__ = ["entrypoint", "main"]

if __name__ == "__main__":
    sys.exit(main(prog="python -m camdegrade"))
