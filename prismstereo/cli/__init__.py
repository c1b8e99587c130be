"""The ``prismstereo`` command line, one module per command. It only parses arguments, calls the library and prints.

Commands: ``rig show``, ``rig preset`` (:mod:`~prismstereo.cli.rig`), ``render``, ``fov``, ``design``, ``match``,
``depth``, ``export``, ``calibrate``, ``train``, ``demo`` (each :mod:`prismstereo.cli.<command>`, registering itself
with its ``add_parser``); ``--version``. Errors of the library (:class:`~prismstereo.errors.PrismStereoError`) end
the command with one line and status 2.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from prismstereo import __version__
from prismstereo.cli import calibrate, demo, depth, design, export, fov, match, render, rig, train
from prismstereo.errors import PrismStereoError

__all__ = ["build_parser", "main"]

COMMANDS = (rig, render, fov, design, match, depth, export, calibrate, train, demo)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``prismstereo`` command."""
    parser = argparse.ArgumentParser(prog="prismstereo", description="Single-lens bi-prism stereo.")
    parser.add_argument("--version", action="version", version=f"prismstereo {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for command in COMMANDS:
        command.add_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``prismstereo`` console script. Returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not hasattr(args, "func"):
        parser.print_help(sys.stderr)
        return 2
    try:
        return args.func(args)
    except PrismStereoError as exc:
        print(f"prismstereo: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
