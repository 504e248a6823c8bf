"""``companion``: the parser, the subcommand registry and the exit-code contract.

    companion simulate MISSION.yaml [--variant V] [--out DIR]   headless flight, summary + plot
    companion sweep table1|table2|table3 [--out DIR]            the paper's Tables I-III
    companion sweep weights                                     score weights vs flight time
    companion run | validate | plan | upload | schema           flying commands (companion.app)
    companion bench                                             the Table IV ablation (companion.bench)
    companion import | replay                                   .plan / GeoJSON in, an animation out

Exit codes (:mod:`companion.cli.errors`): 0 success, 1 mission failure, 2 bad input (one line,
no traceback).

Each subcommand module registers its own parsers; a handler is stored as ``func`` (or ``handler``)
and returns the exit code. To add one, add a registration entry to ``_COMMAND_MODULES``.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Callable, Sequence

from companion.cli.errors import EXIT_OK, BadInput, bad_input

# (module, registration function) of each subcommand group, each f(subparsers) -> None.
_COMMAND_MODULES = (
    ("companion.cli.simulate", "add_parser"),  # simulate
    ("companion.cli.sweep", "add_parser"),  # sweep table1|table2|table3|weights
    ("companion.cli.flying", "add_parser"),  # run
    ("companion.cli.mission", "add_parsers"),  # validate, plan, upload, schema
    ("companion.cli.bench", "add_parser"),  # bench
    ("companion.cli.formats", "add_parsers"),  # import, replay
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="companion", description="A*-BDWA cooperative obstacle avoidance for a pair of UAVs.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module_name, function in _COMMAND_MODULES:
        getattr(importlib.import_module(module_name), function)(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    handler: Callable[[argparse.Namespace], int] = getattr(args, "func", None) or args.handler
    try:
        return int(handler(args))
    except BadInput as exc:
        return bad_input(exc)
    except KeyboardInterrupt:
        print("companion: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # e.g. `companion simulate ... | head`: the reader left, not an error
        import os
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
