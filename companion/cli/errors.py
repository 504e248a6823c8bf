"""The exit codes of every ``companion`` subcommand, and the one base class of input errors.

    0  success
    1  mission failure (the flight did not succeed, a link or a vehicle failed)
    2  bad input: one line naming the problem (``file:line: field.path: reason``), no traceback

A handler raises :class:`BadInput` (or a subclass) for anything the user must fix;
:func:`companion.cli.main` (or the bench's guard) prints it as one line and exits 2.
"""

from __future__ import annotations

import sys

from uav_model.mission import MissionError

EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT = 0, 1, 2


class BadInput(ValueError):
    """A command-line value (or a file it names) that cannot be used; exit 2 with ``str()`` as the line."""


def bad_input(exc: Exception, prog: str = "companion") -> int:
    """One line on stderr (a MissionError already reads ``file:line: field: reason``); exit 2."""
    print(str(exc) if isinstance(exc, MissionError) else f"{prog}: {exc}", file=sys.stderr)
    return EXIT_BAD_INPUT
