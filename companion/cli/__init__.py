"""``companion``: the command line, one module per group of subcommands.

    app.py            the parser, the subcommand registry and the exit-code contract
    errors.py         the exit codes and :class:`BadInput`, the one base of input errors
    options.py        options several subcommands share (variant, plant, --out, certificate ...)
    simulate.py       ``companion simulate``: a headless flight, summary + plot
    sweep.py          ``companion sweep table1|table2|table3``: the paper's Tables I-III
    sweep_weights.py  ``companion sweep weights``: score weights against flight time
    flying.py         ``companion run``: fly over MAVLink (embedded stub, --connect, --sim px4, --in-process)
    sim_options.py    ``companion run``'s choice of simulator and the options each one takes
    mission.py        ``companion validate | plan | upload | schema``
    bench.py          ``companion bench``: the Table IV ablation
    formats.py        ``companion import | replay``

Exit codes, for every subcommand:

    0  success
    1  mission failure (the flight did not succeed, a link or a vehicle failed)
    2  bad input: one line naming the problem (``file:line: field.path: reason``), no traceback

The entry point is :func:`main` (the ``companion`` script; ``python -m companion`` and
``python -m companion.cli`` run it too). :mod:`companion.cli.app` imports only the errors at
import time and each command module when the parser is built, so the modules that raise
:class:`companion.cli.errors.BadInput` (``companion.sitl``, the bench) import it without a cycle.
"""

from companion.cli.app import build_parser, main

__all__ = ["build_parser", "main"]
