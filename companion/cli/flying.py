"""``companion run``: fly the mission over MAVLink, on the embedded stub, external autopilots
(``--connect``), PX4 SITL (``--sim px4``) or in process (``--in-process``).

The handler returns the exit code: 0 success, 1 mission failure (the flight did not succeed, a
link or a vehicle failed), 2 bad input (one line, no traceback, nothing armed).
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import signal
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from companion.app.event_loop import leave, run_bounded
from companion.app.flight_plan import FlightPlan
from companion.app.pilot import RunSettings
from companion.app.preflight import PreflightSettings
from companion.app.results import release_reserve
from companion.app.run_record import LinkRecord
from companion.app.live_run import RunResult, run_mission, save_run, summary_table
from companion.cli.errors import EXIT_BAD_INPUT, EXIT_FAILED, EXIT_OK, BadInput
from companion.cli.options import (add_certificate_options, add_no_fence_option, add_plant_option,
                                   add_signing_key_option, add_variant_option, connect_pair, connections, output_dir,
                                   planned, positive, printer, quiet_mavsdk, signing_key)
from companion.cli.sim_options import add_sim_options, inprocess_options, px4_options
from companion.errors import CompanionError, PreflightRefused
from companion.sitl.embedded import DEFAULT_PORT_BASE, StubOptions, choose_port_base, embedded_stub
from companion.sitl.px4 import Px4Options, px4_sitl

if TYPE_CHECKING:
    from companion.sitl.inprocess import InProcessOptions


def _port(text: str) -> int:
    value = int(text)
    if not 1 <= value <= 65535 - 8:
        raise argparse.ArgumentTypeError(f"{value} is not a usable UDP port")
    return value


def _probability(text: str) -> float:
    value = float(text)
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"{text}: must be a probability in [0, 1]")
    return value


TELEMETRY_HZ = (2.0, 50.0)  # under 2 Hz a position is older than the stale bound allows; over 50, PX4's own rates


def _telemetry_hz(text: str) -> float:
    value = float(text)
    if not TELEMETRY_HZ[0] <= value <= TELEMETRY_HZ[1]:
        raise argparse.ArgumentTypeError(f"{text}: must be {TELEMETRY_HZ[0]:g} to {TELEMETRY_HZ[1]:g} Hz")
    return value


def _blackout(text: str) -> str:
    from sim_bridge.faults import Blackout, FaultSpecError
    try:
        Blackout.parse(text)
    except FaultSpecError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register run on the ``companion`` parser."""
    p = sub.add_parser("run", help="fly the mission over MAVLink (embedded stub unless --connect)",
                       description="Fly every vehicle of the mission with A*-BDWA over MAVSDK. Without --connect "
                                   "the bundled sim_bridge is started on loopback and stopped on exit.")
    p.add_argument("mission", type=Path)
    p.add_argument("--connect", type=connect_pair, action="append", default=[], metavar="NAME=URL",
                   help="fly an external autopilot, e.g. a=udpin://0.0.0.0:14540 (one per vehicle)")
    add_variant_option(p)
    add_plant_option(p, live=True)
    p.add_argument("--out", type=Path, default=None, metavar="DIR",
                   help="write summary.json, flight.csv, traffic.csv, trajectory.png (and the stub's .tlog) here")
    p.add_argument("--speedup", type=positive, default=None,
                   help="embedded stub: sim seconds per wall second (default 1); with --in-process: pace the "
                        "sim at this factor (default: as fast as the loop turns)")
    p.add_argument("--loss", type=_probability, default=0.0, metavar="P", help="embedded stub: API packet loss")
    p.add_argument("--latency-ms", type=float, default=0.0, metavar="MS", help="embedded stub: added API latency")
    p.add_argument("--blackout", type=_blackout, action="append", default=[], metavar="START:DURATION",
                   help="embedded stub: API link blackout in sim seconds (repeatable), e.g. 150:3")
    p.add_argument("--seed", type=int, default=0, help="embedded stub: fault-injection seed")
    p.add_argument("--port-base", type=_port, default=None,
                   help=f"embedded stub: vehicle i talks to PORT_BASE + i (default: {DEFAULT_PORT_BASE}, or the next "
                        "free block when another autopilot is already there)")
    p.add_argument("--gcs-port", type=_port, default=14550, help="embedded stub: GCS link port (default 14550)")
    p.add_argument("--progress-every", type=positive, default=20.0, metavar="S",
                   help="a progress line per vehicle every S sim seconds (default 20)")
    p.add_argument("--no-land", action="store_true", help="hold at the station instead of landing")
    add_sim_options(p)
    add_no_fence_option(p)
    add_certificate_options(p)
    p.add_argument("--shared-clock", action=argparse.BooleanOptionalAction, default=None,
                   help="with --connect: every vehicle stamps telemetry with one sim clock (an external sim-bridge), "
                        "or --no-shared-clock: each has its own (separate PX4 instances). Default: detected from "
                        "the vehicles' clocks at connect, which cannot tell apart PX4 instances booted together; "
                        "--sim px4 knows its instances are separate")
    p.add_argument("--keep-failsafe", action="store_true",
                   help="leave the autopilot's COM_OBL_RC_ACT as it is (PX4's default: Return on an offboard loss) "
                        "instead of setting 5 (Hold); the companion resumes OFFBOARD from either")
    p.add_argument("--plan-from-current", action="store_true",
                   help="plan from where each vehicle is and its heading, instead of refusing a vehicle that is "
                        "away from its mission station")
    p.add_argument("--station-tolerance", type=positive, default=None, metavar="M",
                   help="how far a vehicle may be from its mission station (default: twice the arrival radius)")
    p.add_argument("--connect-timeout", type=positive, default=15.0, metavar="S", help="wall seconds (default 15)")
    p.add_argument("--telemetry-hz", type=_telemetry_hz, default=RunSettings.telemetry_hz, metavar="HZ",
                   help="attitude, position and velocity rate asked of each autopilot, per second of its clock "
                        f"({TELEMETRY_HZ[0]:g}-{TELEMETRY_HZ[1]:g}, default %(default)g); lower it for many vehicles "
                        "or a high --speedup")
    add_signing_key_option(p, "; the embedded stub gets the key too")
    p.add_argument("--in-process", action="store_true",
                   help="no stub process and no sockets: fly the stub's vehicles inside the companion on one sim "
                        "clock, deterministically and faster than real time (same outputs, no .tlog)")
    p.set_defaults(func=cmd_run)


@planned
def cmd_run(args: argparse.Namespace, plan: FlightPlan) -> int:
    if args.signing_key is not None and args.in_process:
        raise BadInput("--signing-key: --in-process has no MAVLink link to sign")
    conns = connections(plan, args.connect) if args.connect else None
    key = signing_key(args, conns or {})
    inproc = inprocess_options(args) if args.in_process else None
    out = None if args.out is None else output_dir(args.out, reserve=True)
    px4 = px4_options(args, plan.mission, out)
    log_file = quiet_mavsdk(out)
    # The embedded stub runs one clock; the PX4 instances --sim px4 starts run one each.
    shared_clock = True if conns is None and px4 is None else False if px4 is not None else None
    settings = RunSettings(shared_clock=shared_clock if args.shared_clock is None else args.shared_clock,
                           connect_timeout_s=args.connect_timeout, telemetry_hz=args.telemetry_hz,
                           progress_every_s=args.progress_every,
                           land=not args.no_land, failsafe_hold=not args.keep_failsafe, signing_key=key)
    checks = PreflightSettings(station_tolerance_m=args.station_tolerance, plan_from_current=args.plan_from_current,
                               set_failsafe_hold=not args.keep_failsafe)
    stub = None
    if conns is None and inproc is None and px4 is None:
        stub = StubOptions(speedup=args.speedup or 1.0, api_port_base=args.port_base, gcs_port=args.gcs_port,
                           loss=args.loss, latency_ms=args.latency_ms, seed=args.seed,
                           blackouts=tuple(args.blackout), tlog_dir=out, signing_key_file=args.signing_key,
                           log_path=None if out is None else out / "sim_bridge.log")
    elif conns is not None and (args.speedup not in (None, 1.0) or args.loss or args.latency_ms or args.blackout):
        print("companion: note: --speedup/--loss/--latency-ms/--blackout only apply to the embedded stub; "
              "ignored with --connect", file=sys.stderr)
    # The certificate is seconds of numpy: work it out before anything spins. Beside the in-process
    # fleet's busy loop, a worker thread's GIL hand-offs stalled it (and the fleet) for minutes.
    _ = plan.certificate
    if plan.coordinated is not None:  # the timed variant's schedule, for the same reason
        print(f"schedule: departure hold of {plan.mission.by_priority[0].name} {plan.coordinated.hold_s:.1f} s; "
              + ", ".join(f"{n} {b.value}" for n, b in plan.coordinated.blocking.items()), flush=True)
    stub_notices: list[str] = []  # the embedded stub's own output problems (its .tlog)
    try:
        result = run_bounded(_run(plan, conns, stub, settings, out, inproc, checks, px4, stub_notices))
    except PreflightRefused as exc:
        print(f"companion: refused: {exc}; nothing was armed", file=sys.stderr)
        return leave(EXIT_BAD_INPUT)
    except CompanionError as exc:
        print(f"companion: {exc}", file=sys.stderr)
        return leave(EXIT_FAILED)
    finally:  # the flight's writers (logs, stub) are done: the results may use the space now
        if out is not None:
            release_reserve(out)
    print(summary_table(plan, result), flush=True)  # the verdict first: it needs no disk
    if out is not None:
        problems = tuple(stub_notices) + ((log_file.problem,) if log_file is not None and log_file.problem else ())
        saved = save_run(out, plan, result, problems)
        tlog = ("the stub's .tlog" if stub is not None else "no .tlog (in process: no link to record)"
                if inproc is not None else "no .tlog (MAVSDK cannot record one; use a GCS)")
        logs = ", flight.csv, traffic.csv, companion.log and " + tlog if saved.complete else ""
        print(saved.line() + logs, file=sys.stdout if saved.complete else sys.stderr, flush=True)
    return leave(EXIT_OK if result.success else EXIT_FAILED)


async def _run(plan: FlightPlan, conns: dict[str, str] | None, stub: StubOptions | None,
               settings: RunSettings, out: Path | None, inproc: InProcessOptions | None = None,
               checks: PreflightSettings = PreflightSettings(), px4: Px4Options | None = None,
               stub_notices: list[str] | None = None) -> RunResult:
    started = time.monotonic()
    report = printer(started)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    main = asyncio.current_task()
    assert main is not None

    def on_signal(sig: signal.Signals) -> None:
        if not stop.is_set():
            report(f"{sig.name}: stopping; vehicles will hold (send it again to quit at once)")
            stop.set()
        else:
            main.cancel()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, on_signal, sig)
    try:
        link = LinkRecord(conns or "embedded", *((None, None, None) if stub is None
                                                  else (stub.speedup, stub.loss, stub.latency_ms)))
        if inproc is not None:
            from companion.sitl.inprocess import open_inprocess_fleet
            link = dataclasses.replace(link, connections="in-process", speedup=inproc.speedup)
            pace = "as fast as the loop turns" if inproc.speedup is None else f"at {inproc.speedup:g}x"
            report(f"flying in process (no stub process, no sockets), {pace}")
            async with open_inprocess_fleet(plan.mission, inproc) as fleet:
                return await run_mission(plan, fleet.connections(), settings, out, report, stop, link,
                                         open_vehicle=fleet.open_vehicle, checks=checks)
        if px4 is not None:
            link = dataclasses.replace(link, connections="px4", speedup=px4.speedup)
            async with px4_sitl(plan.mission, px4, report) as px4_conns:
                return await run_mission(plan, px4_conns, settings, out, report, stop, link, checks=checks)
        if stub is None:
            assert conns is not None
            return await run_mission(plan, conns, settings, out, report, stop, link, checks=checks)
        base, note = await choose_port_base(len(plan.mission.vehicles), stub.api_port_base, stub.gcs_port)
        if note:
            report(note)
        stub = dataclasses.replace(stub, api_port_base=base)
        report(f"starting the embedded sim_bridge at {stub.speedup:g}x on 127.0.0.1:{stub.api_port_base}+i")
        async with embedded_stub(plan.mission, stub, notices=stub_notices) as embedded_conns:
            return await run_mission(plan, embedded_conns, settings, out, report, stop, link, checks=checks)
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(sig)
