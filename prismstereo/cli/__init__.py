"""The ``prismstereo`` command line, one module per command. It only parses arguments, calls the library and prints.

Commands: ``rig show``, ``rig preset`` (:mod:`~prismstereo.cli.rig`), ``render``, ``fov``, ``design``, ``match``,
``depth``, ``export``, ``calibrate``, ``train``, ``demo`` (each :mod:`prismstereo.cli.<command>`, registering itself
with its ``add_parser``); ``--version``. Errors of the library (:class:`~prismstereo.errors.PrismStereoError`) end
the command with one line and status 2; Ctrl-C and SIGTERM with one line (what was written) and status 130 / 143.
"""

from __future__ import annotations

import argparse
import importlib
import signal
import sys
from collections.abc import Sequence

from prismstereo import __version__
from prismstereo.errors import PrismStereoError

__all__ = ["COMMANDS", "Terminated", "build_parser", "main"]

COMMANDS = ("rig", "render", "fov", "design", "match", "depth", "export", "calibrate", "train", "demo")
"""The commands, each the module :mod:`prismstereo.cli.<command>` (imported when its parser is built)."""


def build_parser(commands: Sequence[str] = COMMANDS) -> argparse.ArgumentParser:
    """The argument parser of the ``prismstereo`` command with the parsers of ``commands`` (default all): running
    one command imports only its module (``prismstereo depth --help`` does not import torch).

    Example:
        >>> build_parser(["fov"]).parse_args(["fov"]).command
        'fov'
    """
    parser = argparse.ArgumentParser(prog="prismstereo", description="Single-lens bi-prism stereo.")
    parser.add_argument("--version", action="version", version=f"prismstereo {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in commands:
        importlib.import_module(f"prismstereo.cli.{name}").add_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``prismstereo`` console script. Returns the exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    first = argv[0] if argv else None
    # one command's parser for that command, none for --version, all of them for the overall help
    parser = build_parser([first] if first in COMMANDS else [] if first == "--version" else COMMANDS)
    args = parser.parse_args(argv)
    if not hasattr(args, "func"):
        parser.print_help(sys.stderr)
        return 2
    terminate = _on_sigterm()
    try:
        return args.func(args)
    except PrismStereoError as exc:
        print(f"prismstereo: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM (Terminated): the command's own line says what is left
        detail = f": {exc}" if str(exc) else ""
        print(f"prismstereo: interrupted{detail}", file=sys.stderr)
        return 143 if isinstance(exc, Terminated) else 130
    finally:
        if terminate is not None:
            signal.signal(signal.SIGTERM, terminate)


class Terminated(KeyboardInterrupt):
    """SIGTERM while a command runs: it unwinds as Ctrl-C does (files closed, partial ones removed); exit 143."""


def _on_sigterm():
    """Turn SIGTERM into :class:`Terminated` while the command runs; returns the previous handler (None where
    signals cannot be set: not the main thread)."""

    def terminated(signum, frame):
        raise Terminated()

    try:
        return signal.signal(signal.SIGTERM, terminated)
    except ValueError:
        return None


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
