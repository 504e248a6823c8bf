"""``sim-bridge MISSION.yaml [options]``: run the PX4-like stub for every vehicle of a mission."""

from __future__ import annotations

import argparse
import asyncio
import logging
import signal
import sys
from pathlib import Path

from uav_model.mission import MissionError, load_mission
from uav_model.signing_key import SigningKeyError, load_signing_key
from sim_bridge.admission import parse_sysids
from sim_bridge.bridge import SimBridge, SimBridgeError, SimOptions, run_stub
from sim_bridge.clock import ClockError, SimClock
from sim_bridge.faults import Blackout, FaultConfig, FaultSpecError
from sim_bridge.vehicle.px4 import default_params

log = logging.getLogger("sim_bridge")
_MISSION_DEPENDENT = frozenset({"MAV_SYS_ID"})  # bounds depend on the vehicle: checked when it is built


def _port(text: str) -> int:
    value = int(text)
    if not 1 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"{value} is not a UDP port (1..65535)")
    return value


def _blackout(text: str) -> Blackout:
    try:
        return Blackout.parse(text)
    except FaultSpecError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _param(text: str) -> tuple[str, float]:
    name, sep, value = text.partition("=")
    try:
        if not sep or not name:
            raise ValueError
        return name.strip().upper(), float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected NAME=VALUE, e.g. COM_OBL_RC_ACT=5") from None


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="sim-bridge", description=(
        "PX4-like kinematic SITL stub: one MAVLink vehicle per mission vehicle. Vehicle i sends "
        "to HOST:API_PORT_BASE+i (connect MAVSDK with udpin://HOST:14540+i); a GCS link on "
        "HOST:GCS_PORT carries every vehicle."))
    p.add_argument("mission", type=Path, help="mission YAML file")
    p.add_argument("--speedup", type=float, default=1.0, help="sim seconds per wall second (default 1)")
    p.add_argument("--host", default="127.0.0.1", help="where the companion and GCS listen (default 127.0.0.1)")
    p.add_argument("--bind", default=None, help="local address of the stub's sockets "
                   "(default: 127.0.0.1 if --host is loopback, else 0.0.0.0)")
    p.add_argument("--api-port-base", type=_port, default=14540, help="vehicle i sends to this port + i (default 14540)")
    p.add_argument("--gcs-port", type=_port, default=14550, help="GCS link port (default 14550)")
    p.add_argument("--no-gcs", action="store_true", help="no GCS link")
    p.add_argument("--loss", type=float, default=0.0, metavar="P", help="API link packet loss probability")
    p.add_argument("--latency-ms", type=float, default=0.0, metavar="MS", help="added API link latency (wall ms)")
    p.add_argument("--blackout", type=_blackout, action="append", default=[], metavar="START:DURATION",
                   help="API link blackout in sim seconds (repeatable), e.g. 30:5")
    p.add_argument("--tlog", type=Path, default=None, metavar="DIR",
                   help="record the GCS stream as DIR/*.tlog, stamped in sim time")
    p.add_argument("--tlog-per-vehicle", action="store_true", help="with --tlog: also one .tlog per vehicle")
    p.add_argument("--seed", type=int, default=0, help="seed of the fault injection (default 0)")
    p.add_argument("--physics-dt", type=float, default=0.02, metavar="S", help="physics step in sim s (default 0.02)")
    p.add_argument("--speed-headroom", type=float, default=1.0,
                   help="vehicle speed limit as a multiple of the mission speed (default 1.0)")
    p.add_argument("--param", type=_param, action="append", default=[], metavar="NAME=VALUE",
                   help="a parameter value at boot (repeatable), e.g. COM_OBL_RC_ACT=5")
    p.add_argument("--allow-sysid", default=None, metavar="IDS",
                   help="obey only messages from these system ids, e.g. 255,245 (QGroundControl/MAVProxy, MAVSDK); "
                        "others are dropped and logged (default: anyone, as PX4 without signing)")
    p.add_argument("--signing-key", type=Path, default=None, metavar="FILE",
                   help="MAVLink 2 signing: sign every frame and drop unsigned ones (HEARTBEAT, RADIO_STATUS "
                        "excepted); FILE holds 32 raw bytes, 64 hex digits or a passphrase (SHA-256, as MAVProxy)")
    p.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    return p


def options_from_args(args: argparse.Namespace) -> SimOptions:
    """Validated options; raises ValueError with a one-line message."""
    faults = FaultConfig(loss_p=args.loss, latency_ms=args.latency_ms, blackouts=tuple(args.blackout))
    SimClock(args.speedup, args.physics_dt, 0.0)  # validates speedup and step
    if not 0.1 <= args.speed_headroom <= 10.0:
        raise ValueError(f"speed headroom {args.speed_headroom}: must be in [0.1, 10]")
    defs = {d.name: d for d in default_params(1, 1.0, 1.0, 1.0, 1.0)}
    for name, value in args.param:
        if name not in defs:
            raise ValueError(f"--param {name}: unknown parameter")
        if name not in _MISSION_DEPENDENT and not defs[name].accepts(value):
            raise ValueError(f"--param {name}={value:g}: outside [{defs[name].min_value:g}, {defs[name].max_value:g}]")
    allow = None if args.allow_sysid is None else parse_sysids(args.allow_sysid)
    key = None if args.signing_key is None else load_signing_key(args.signing_key)
    return SimOptions(speedup=args.speedup, host=args.host, bind_host=args.bind, api_port_base=args.api_port_base,
                      gcs_port=None if args.no_gcs else args.gcs_port, physics_dt_s=args.physics_dt, seed=args.seed,
                      faults=faults, tlog_dir=args.tlog, tlog_per_vehicle=args.tlog_per_vehicle,
                      speed_headroom=args.speed_headroom, params=tuple(args.param), allow_sysids=allow,
                      signing_key=key)


async def _serve(mission, options: SimOptions) -> None:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)

    def ready(sim: SimBridge) -> None:
        for i, v in enumerate(sim.vehicles):
            port = options.api_port(i)
            print(f"vehicle {v.name}: sysid {v.system_id} -> {options.host}:{port} "
                  f"(companion: udpin://{options.host}:{port})", flush=True)
        if options.gcs_port is not None:
            print(f"GCS link -> {options.host}:{options.gcs_port}", flush=True)
        for path in sim.tlog_paths:
            print(f"tlog: {path}", flush=True)
        if options.allow_sysids is not None:
            print(f"obeys system ids {','.join(map(str, sorted(options.allow_sysids)))} only", flush=True)
        if options.signing_key is not None:
            print("MAVLink 2 signing on: frames signed; unsigned ones dropped", flush=True)
        print(f"running at {options.speedup:g}x; Ctrl-C to stop", flush=True)

    await run_stub(mission, options, stop=stop, on_ready=ready)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        mission = load_mission(args.mission)
        options = options_from_args(args)
    except (MissionError, FaultSpecError, ClockError, ValueError, SigningKeyError) as exc:
        print(f"sim-bridge: {exc}", file=sys.stderr)
        return 2
    try:
        asyncio.run(_serve(mission, options))
    except SimBridgeError as exc:
        print(f"sim-bridge: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:  # a second Ctrl-C during shutdown
        return 130
    return 0
