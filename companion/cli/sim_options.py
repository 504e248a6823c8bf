"""``companion run``'s choice of simulator and the options each one takes.

    (default)      the embedded sim_bridge stub (companion.sitl.embedded)
    --sim px4      real PX4 SITL with SIH physics, one instance per vehicle (companion.sitl.px4)
    --in-process   the stub's vehicles inside the companion, no sockets (companion.sitl.inprocess)

Each ``*_options`` function turns the parsed arguments into that simulator's options, or raises
BadInput (exit 2, one line) for an option that simulator cannot take.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from companion.cli.errors import BadInput
from companion.sitl.px4 import API_PORT_BASE, GCS_PORT, PX4_DIR_ENV, Px4Options, check_system_ids, find_px4
from uav_model.mission import Mission

if TYPE_CHECKING:
    from companion.sitl.inprocess import InProcessOptions


def add_sim_options(parser: argparse.ArgumentParser) -> None:
    """``companion run``'s ``--sim`` and ``--px4-dir``."""
    parser.add_argument("--sim", choices=("stub", "px4"), default="stub",
                        help="without --connect: fly the bundled stub (default) or real PX4 SITL with SIH physics, "
                             "one instance per vehicle at its start station (needs --px4-dir or PX4_SITL_DIR)")
    parser.add_argument("--px4-dir", type=Path, default=None, metavar="DIR",
                        help=f"--sim px4: a PX4 SITL build directory with bin/px4 and etc/ (default: ${PX4_DIR_ENV})")


def px4_options(args: argparse.Namespace, mission: Mission, out: Path | None) -> Px4Options | None:
    """``--sim px4``'s launch options (None for the stub); BadInput for what PX4 SITL cannot take."""
    if args.sim != "px4":
        if args.px4_dir is not None:
            raise BadInput("--px4-dir only applies with --sim px4")
        return None
    if args.connect or args.in_process:
        raise BadInput(f"--sim px4 starts PX4 SITL itself; it cannot be combined with "
                       f"{'--connect' if args.connect else '--in-process'}")
    if args.loss or args.latency_ms or args.blackout:
        raise BadInput("--loss/--latency-ms/--blackout are the embedded stub's fault injection; PX4 SITL has none")
    if args.port_base is not None or args.gcs_port != GCS_PORT:
        raise BadInput(f"--port-base/--gcs-port: PX4 SITL's ports are fixed ({API_PORT_BASE} + i, {GCS_PORT})")
    check_system_ids(mission)
    return Px4Options(find_px4(args.px4_dir), speedup=args.speedup or 1.0, log_dir=out)


def inprocess_options(args: argparse.Namespace) -> InProcessOptions:
    """--in-process: refuse what only the UDP path has; the speed factor is checked by the sim clock."""
    from companion.sitl.inprocess import InProcessOptions
    from sim_bridge.clock import ClockError
    if args.connect:
        raise BadInput("--in-process flies the stub's vehicles inside the companion; "
                       "it cannot be combined with --connect")
    if args.loss or args.latency_ms or args.blackout:
        raise BadInput("--loss/--latency-ms/--blackout act on the embedded stub's UDP link; "
                       "there is none with --in-process")
    try:
        return InProcessOptions(speedup=args.speedup)
    except ClockError as exc:
        raise BadInput(f"--speedup: {exc}") from None
