"""What every ``companion`` subcommand shares: the exit codes and what bad input looks like.

    0  success
    1  mission failure (the flight did not succeed, a link or a vehicle failed)
    2  bad input: one line naming the problem (``file:line: field.path: reason``), no traceback

A handler raises :class:`BadInput` (or returns :func:`bad_input`) for anything the user must fix;
``companion.cli.main`` turns a raised one into its line and exit 2.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from uav_model.mission import VARIANTS, MissionError

EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT = 0, 1, 2


class BadInput(ValueError):
    """A command-line value that cannot be used; exit 2 with this one-line message."""


def bad_input(exc: Exception) -> int:
    """One line on stderr (a MissionError already reads ``file:line: field: reason``); exit 2."""
    print(str(exc) if isinstance(exc, MissionError) else f"companion: {exc}", file=sys.stderr)
    return EXIT_BAD_INPUT


def output_dir(path: Path) -> Path:
    """``--out``, created if need be; BadInput when it cannot be."""
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise BadInput(f"--out {path}: cannot create the directory ({exc.strerror})") from None
    return path


def add_variant_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--variant", choices=VARIANTS, default=None, help="planner variant (default: the mission's)")
