"""The flying subcommands of ``companion``: run, validate, plan, upload, schema.

``companion.cli`` builds the parser and calls :func:`add_commands`; each subcommand stores its
handler in ``func``, which returns the exit code:

    0  success
    1  mission failure (the flight did not succeed, a link or a vehicle failed)
    2  bad input: one line ``file:line: field.path: reason``, no traceback, nothing armed
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import functools
import json
import logging
import math
import signal
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from companion.sitl.embedded import DEFAULT_PORT_BASE, StubOptions, choose_port_base, embedded_stub
from companion.sitl.options import add_sim_options, inprocess_options, px4_options
from companion.sitl.px4 import Px4Options, px4_sitl
from companion.app.event_loop import leave, run_bounded
from companion.app.flight_plan import FlightPlan, prepare, verify_readback
from companion.app.pilot import RunSettings
from companion.app.preflight import PreflightSettings
from companion.app.results import release_reserve
from companion.app.runner import RunResult, run_mission, save_run, summary_table
from companion.errors import CompanionError, PreflightRefused
from companion.cli_common import (EXIT_BAD_INPUT, EXIT_FAILED, EXIT_OK, BadInput, add_certificate_options,
                                  add_no_fence_option, add_variant_option, bad_input, connections, output_dir,
                                  quiet_mavsdk, with_certificate_options)
from uav_model.fence_margin import fence_warnings
from uav_model.mission import MissionError, load_mission, mission_schema, shared_goals

if TYPE_CHECKING:
    from companion.sitl.inprocess import InProcessOptions

log = logging.getLogger("companion")


# -- argument helpers ---------------------------------------------------------------------
def _connect(text: str) -> tuple[str, str]:
    name, sep, url = text.partition("=")
    if not sep or not name or not url:
        raise argparse.ArgumentTypeError(f"--connect {text!r}: expected NAME=URL, e.g. a=udpin://0.0.0.0:14540")
    if "://" not in url:
        raise argparse.ArgumentTypeError(f"--connect {text!r}: {url!r} is not a MAVSDK URL (udpin://HOST:PORT, "
                                         "udpout://, tcpout://, serial://DEV:BAUD)")
    return name, url


def _port(text: str) -> int:
    value = int(text)
    if not 1 <= value <= 65535 - 8:
        raise argparse.ArgumentTypeError(f"{value} is not a usable UDP port")
    return value


def _positive(text: str) -> float:
    value = float(text)
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"{text}: must be a positive number")
    return value


def _probability(text: str) -> float:
    value = float(text)
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"{text}: must be a probability in [0, 1]")
    return value


def _blackout(text: str) -> str:
    from sim_bridge.faults import Blackout, FaultSpecError
    try:
        Blackout.parse(text)
    except FaultSpecError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Register run, validate, plan, upload and schema on the ``companion`` parser."""
    p = sub.add_parser("run", help="fly the mission over MAVLink (embedded stub unless --connect)",
                       description="Fly every vehicle of the mission with A*-BDWA over MAVSDK. Without --connect "
                                   "the bundled sim_bridge is started on loopback and stopped on exit.")
    p.add_argument("mission", type=Path)
    p.add_argument("--connect", type=_connect, action="append", default=[], metavar="NAME=URL",
                   help="fly an external autopilot, e.g. a=udpin://0.0.0.0:14540 (one per vehicle)")
    add_variant_option(p)
    p.add_argument("--out", type=Path, default=None, metavar="DIR",
                   help="write summary.json, flight.csv, traffic.csv, trajectory.png (and the stub's .tlog) here")
    p.add_argument("--speedup", type=_positive, default=None,
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
    p.add_argument("--progress-every", type=_positive, default=20.0, metavar="S",
                   help="a progress line per vehicle every S sim seconds (default 20)")
    p.add_argument("--no-land", action="store_true", help="hold at the station instead of landing")
    add_sim_options(p)
    add_no_fence_option(p)
    add_certificate_options(p)
    p.add_argument("--shared-clock", action="store_true", default=None,
                   help="with --connect: assert that every vehicle stamps telemetry with one sim clock (an external "
                        "sim-bridge). Not needed: the companion detects it when the vehicles' clocks agree")
    p.add_argument("--keep-failsafe", action="store_true",
                   help="leave the autopilot's COM_OBL_RC_ACT as it is (PX4's default: Return on an offboard loss) "
                        "instead of setting 5 (Hold); the companion resumes OFFBOARD from either")
    p.add_argument("--plan-from-current", action="store_true",
                   help="plan from where each vehicle is and its heading, instead of refusing a vehicle that is "
                        "away from its mission station")
    p.add_argument("--station-tolerance", type=_positive, default=None, metavar="M",
                   help="how far a vehicle may be from its mission station (default: twice the arrival radius)")
    p.add_argument("--connect-timeout", type=_positive, default=15.0, metavar="S", help="wall seconds (default 15)")
    p.add_argument("--signing-key", type=Path, default=None, metavar="FILE",
                   help="MAVLink 2 signing: refused, because MAVSDK (the companion's MAVLink library) has no signing "
                        "API; see docs/companion.md, 'Links and signing'")
    p.add_argument("--in-process", action="store_true",
                   help="no stub process and no sockets: fly the stub's vehicles inside the companion on one sim "
                        "clock, deterministically and faster than real time (same outputs, no .tlog)")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("validate", help="check a mission file (schema, geometry, reachability)")
    p.add_argument("mission", type=Path)
    add_variant_option(p)
    add_certificate_options(p)
    p.set_defaults(func=cmd_validate)

    p = sub.add_parser("plan", help="global routes and a plot, no vehicles")
    p.add_argument("mission", type=Path)
    add_variant_option(p)
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="write routes.json and trajectory.png here")
    p.set_defaults(func=cmd_plan)

    p = sub.add_parser("upload", help="plan, upload the routes as MAVLink missions and the geofence, read them back")
    p.add_argument("mission", type=Path)
    p.add_argument("--connect", type=_connect, action="append", default=[], metavar="NAME=URL", required=True)
    add_variant_option(p)
    p.add_argument("--connect-timeout", type=_positive, default=15.0, metavar="S")
    add_no_fence_option(p)
    p.set_defaults(func=cmd_upload)

    p = sub.add_parser("schema", help="print the mission JSON Schema")
    p.set_defaults(func=cmd_schema)


# -- shared steps -------------------------------------------------------------------------
def _planned(handler: Callable[[argparse.Namespace, FlightPlan], int]) -> Callable[[argparse.Namespace], int]:
    """A subcommand on the mission's plan: a bad file or an unreachable goal exits 2 before it starts."""
    @functools.wraps(handler)
    def with_plan(args: argparse.Namespace) -> int:
        try:
            plan = prepare(load_mission(args.mission), args.variant)
            plan = with_certificate_options(dataclasses.replace(plan, geofence=not getattr(args, "no_fence", False)), args)
        except MissionError as exc:
            return bad_input(exc)
        return handler(args, plan)
    return with_plan


def _printer(started: float):
    def report(line: str) -> None:
        print(f"[{time.monotonic() - started:6.1f}s] {line}", flush=True)
        log.info("%s", line)
    return report


# -- commands ------------------------------------------------------------------------------
def cmd_schema(args: argparse.Namespace) -> int:
    print(json.dumps(mission_schema(), indent=2))
    return EXIT_OK


@_planned
def cmd_validate(args: argparse.Namespace, plan: FlightPlan) -> int:
    m = plan.mission
    for station, names in shared_goals(m).items():
        print(f"{m.source}: warning: vehicles {', '.join(names)} share goal station {station!r}: "
              f"only one can hold it; the others will wait near it until the time limit")
    for line in fence_warnings(m):
        print(f"{m.source}: warning: fence: {line}")
    routes = ", ".join(f"{n}: {r.nodes_raw} -> {r.nodes_sparse} nodes" for n, r in plan.routes.items())
    print(f"{m.source}: ok: {len(m.vehicles)} vehicle(s), {len(m.world.obstacles)} obstacle(s) "
          f"({len(m.world.moving_obstacles)} moving), variant {plan.variant}" + (f"; routes {routes}" if routes else ""))
    if plan.certificate is not None:
        print(plan.certificate.describe())
        if (advice := plan.certificate_advice()) is not None:
            print(f"  {advice}")
    return EXIT_OK


@_planned
def cmd_plan(args: argparse.Namespace, plan: FlightPlan) -> int:
    from companion.planning.bounds import lower_bound_s
    out = output_dir(args.out)
    doc: dict = {"mission": plan.mission.name, "variant": plan.variant, "vehicles": {}}
    for v in plan.mission.by_priority:
        nodes = plan.nodes_enu_m(v)
        route = plan.routes.get(v.name)
        bound = lower_bound_s(plan.mission.world, v.start_enu_m, v.goal_enu_m, v.speed_m_s)
        doc["vehicles"][v.name] = {
            "start": v.start, "goal": v.goal, "nodes_raw": None if route is None else route.nodes_raw,
            "nodes_sparse": None if route is None else route.nodes_sparse,
            "constraint": getattr(route, "constraint", None),
            "lower_bound_s": bound,
            "waypoints_enu_m": [[round(float(x), 3), round(float(y), 3)] for x, y in nodes],
            "waypoints_geodetic": [[round(w.lat_deg, 7), round(w.lon_deg, 7), w.alt_rel_m] for w in plan.waypoints(v)],
        }
        print(f"{v.name}: {v.start} -> {v.goal}: "
              + (f"{route.nodes_raw} A* nodes -> {route.nodes_sparse} sparse" if route else "no global route (variant)")
              + f"; lower bound {bound:.1f} s")
    if plan.certificate is not None:
        doc["occlusion_certificate"] = plan.certificate.summary_dict()
        print(plan.certificate.describe())
    (out / "routes.json").write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
    from companion.app.fence import mission_fence
    from companion.formats.qgc_plan import plan_document
    zones = mission_fence(plan.mission)
    for v in plan.mission.vehicles:
        doc = plan_document(plan.mission, v, plan.waypoints(v), zones)
        (out / f"{v.name}.plan").write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
    _save_plan_figure(out / "trajectory.png", plan)
    print(f"wrote {out / 'routes.json'}, {out / 'trajectory.png'} and a QGroundControl .plan per vehicle")
    return EXIT_OK


def _save_plan_figure(path: Path, plan: FlightPlan) -> None:
    """The world with the planned routes (nothing flown yet), moving obstacles swept over the
    longest route's time at cruise."""
    from companion.plots import place_legend, vehicle_colors, world_figure
    nodes = {v.name: plan.nodes_enu_m(v) for v in plan.mission.by_priority}
    t_end = max(sum(math.dist(p, q) for p, q in zip(nodes[v.name][:-1], nodes[v.name][1:])) / v.speed_m_s
                for v in plan.mission.vehicles)
    fig, ax = world_figure(plan.mission, title=f"{plan.mission.name}: planned routes ({plan.variant})",
                           sweep_until_s=t_end)
    colors = vehicle_colors(plan.mission)
    for v in plan.mission.by_priority:
        route = plan.routes.get(v.name)
        if route is not None and len(route.raw_enu_m) != len(nodes[v.name]):
            ax.plot(route.raw_enu_m[:, 0], route.raw_enu_m[:, 1], ls="--", lw=0.8, alpha=0.6, color=colors[v.name],
                    label=f"{v.name}: raw A* ({route.nodes_raw} nodes)")
        ax.plot(nodes[v.name][:, 0], nodes[v.name][:, 1], lw=1.4, marker="o", ms=3.5, color=colors[v.name],
                label=f"{v.name}: uploaded route ({len(nodes[v.name])} waypoints)")
    place_legend(fig, ax)
    fig.savefig(path)


@_planned
def cmd_upload(args: argparse.Namespace, plan: FlightPlan) -> int:
    conns = connections(plan, args.connect)
    quiet_mavsdk(None)
    try:
        run_bounded(_upload(plan, conns, args.connect_timeout, _printer(time.monotonic())))
    except PreflightRefused as exc:  # the geofence refused or read back different
        print(f"companion: refused: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except CompanionError as exc:
        print(f"companion: upload failed: {exc}", file=sys.stderr)
        return EXIT_FAILED
    return EXIT_OK


async def _upload(plan: FlightPlan, conns: dict[str, str], timeout_s: float, report) -> None:
    from companion.app.fence import upload_and_verify_fence
    from companion.vehicle.mavsdk_vehicle import open_mavsdk_vehicle
    for v in plan.mission.vehicles:
        async with open_mavsdk_vehicle(v.name, v.system_id, conns[v.name], plan.mission.origin,
                                       connect_timeout_s=timeout_s) as vehicle:
            waypoints = plan.waypoints(v)
            await vehicle.upload_route(waypoints, plan.mission.planner.acceptance_radius_m)
            got = await vehicle.download_route()
            verify_readback(v.name, waypoints, got)
            report(f"{v.name}: uploaded {len(waypoints)} waypoints to {conns[v.name]} and read them back")
            await upload_and_verify_fence(vehicle, plan, report)


MAVSDK_CANNOT_SIGN = ("--signing-key: the companion cannot sign: MAVSDK {version} has no MAVLink 2 signing API, so an "
                      "autopilot that enforces signing would refuse every command it sends; fly unsigned on a trusted link "
                      "(loopback, a private network) and limit who may command with the autopilot's own means, e.g. "
                      "sim-bridge --allow-sysid (docs/companion.md)")


@_planned
def cmd_run(args: argparse.Namespace, plan: FlightPlan) -> int:
    if args.signing_key is not None:
        from importlib.metadata import version
        raise BadInput(MAVSDK_CANNOT_SIGN.format(version=version("mavsdk")))
    conns = connections(plan, args.connect) if args.connect else None
    inproc = inprocess_options(args) if args.in_process else None
    out = None if args.out is None else output_dir(args.out, reserve=True)
    px4 = px4_options(args, plan.mission, out)
    log_file = quiet_mavsdk(out)
    settings = RunSettings(shared_clock=True if conns is None and px4 is None else args.shared_clock,
                           connect_timeout_s=args.connect_timeout, progress_every_s=args.progress_every,
                           land=not args.no_land, failsafe_hold=not args.keep_failsafe)
    checks = PreflightSettings(station_tolerance_m=args.station_tolerance, plan_from_current=args.plan_from_current,
                               set_failsafe_hold=not args.keep_failsafe)
    stub = None
    if conns is None and inproc is None and px4 is None:
        stub = StubOptions(speedup=args.speedup or 1.0, api_port_base=args.port_base, gcs_port=args.gcs_port,
                           loss=args.loss, latency_ms=args.latency_ms, seed=args.seed,
                           blackouts=tuple(args.blackout), tlog_dir=out,
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
    report = _printer(started)
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
        extra = {"connections": conns or "embedded", "speedup": None if stub is None else stub.speedup,
                 "loss": None if stub is None else stub.loss,
                 "latency_ms": None if stub is None else stub.latency_ms}
        if inproc is not None:
            from companion.sitl.inprocess import open_inprocess_fleet
            extra.update(connections="in-process", speedup=inproc.speedup)
            pace = "as fast as the loop turns" if inproc.speedup is None else f"at {inproc.speedup:g}x"
            report(f"flying in process (no stub process, no sockets), {pace}")
            async with open_inprocess_fleet(plan.mission, inproc) as fleet:
                return await run_mission(plan, fleet.connections(), settings, out, report, stop, extra,
                                         open_vehicle=fleet.open_vehicle, checks=checks)
        if px4 is not None:
            extra.update(connections="px4", speedup=px4.speedup)
            async with px4_sitl(plan.mission, px4, report) as px4_conns:
                return await run_mission(plan, px4_conns, settings, out, report, stop, extra, checks=checks)
        if stub is None:
            assert conns is not None
            return await run_mission(plan, conns, settings, out, report, stop, extra, checks=checks)
        base, note = await choose_port_base(len(plan.mission.vehicles), stub.api_port_base, stub.gcs_port)
        if note:
            report(note)
        stub = dataclasses.replace(stub, api_port_base=base)
        report(f"starting the embedded sim_bridge at {stub.speedup:g}x on 127.0.0.1:{stub.api_port_base}+i")
        async with embedded_stub(plan.mission, stub, notices=stub_notices) as embedded_conns:
            return await run_mission(plan, embedded_conns, settings, out, report, stop, extra, checks=checks)
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(sig)
