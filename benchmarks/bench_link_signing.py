"""The link guard's cost per datagram, with and without MAVLink 2 signing. Prints medians.

    python benchmarks/bench_link_signing.py [--repeat N] [--datagrams N]

Two figures, each alternating the unsigned and the signed guard round by round so that load on
a shared machine hits both alike:

- **work**: what the relay thread does per datagram besides its socket calls: reading the
  frames' system ids (every datagram, both ways) and, with a key, signing a setpoint MAVSDK
  sends (one SHA-256 and two CRCs) or checking an ATTITUDE the autopilot sends (one SHA-256);
- **relay**: one datagram at a time through a real guard over loopback UDP (a fake MAVSDK sends
  a setpoint, a fake autopilot receives it, and back with an ATTITUDE): the wall time per leg,
  socket calls and the relay thread's wake-up included.
"""

from __future__ import annotations

import argparse
import asyncio
import hashlib
import socket
import statistics
import time

from pymavlink.dialects.v20 import common as mavlink

from companion.bench.machine import machine_line
from companion.vehicle.link_guard import LOOPBACK, guarded_port
from companion.vehicle.link_probe import frame_system_ids
from companion.vehicle.link_signing import LinkSigner
from uav_model.signing_key import signing_timestamp

KEY = hashlib.sha256(b"benchmark").digest()


def _setpoint() -> bytes:
    enc = mavlink.MAVLink(None, 245, 190)
    return enc.set_position_target_local_ned_encode(0, 1, 1, mavlink.MAV_FRAME_BODY_NED, 0xDC7, 0, 0, 0,
                                                    10.0, 0, 0, 0, 0, 0, 0, 0.2).pack(enc)


def _attitude_encoder(key: bytes | None) -> mavlink.MAVLink:
    enc = mavlink.MAVLink(None, 1, 1)
    if key is not None:
        enc.signing.secret_key, enc.signing.sign_outgoing = key, True
        enc.signing.timestamp = signing_timestamp()
    return enc


def _attitudes(n: int, key: bytes | None) -> list[bytes]:
    enc = _attitude_encoder(key)
    return [enc.attitude_encode(i, 0.01, 0.02, 1.0, 0.0, 0.0, 0.1).pack(enc) for i in range(n)]


def _work_us(n: int, signed: bool) -> tuple[float, float]:
    """Microseconds per datagram: out (MAVSDK's setpoint) and in (the autopilot's ATTITUDE)."""
    setpoint, attitudes = _setpoint(), _attitudes(n, KEY if signed else None)
    signer = LinkSigner(KEY) if signed else None
    t0 = time.perf_counter()
    for _ in range(n):
        frame_system_ids(setpoint)
        if signer is not None:
            signer.sign(setpoint)
    t1 = time.perf_counter()
    for data in attitudes:
        frame_system_ids(data)
        if signer is not None:
            signer.check(data)
    t2 = time.perf_counter()
    return (t1 - t0) / n * 1e6, (t2 - t1) / n * 1e6


async def _relay_us(n: int, signed: bool) -> tuple[float, float]:
    """Median wall microseconds per datagram through a guard: MAVSDK -> autopilot, autopilot -> MAVSDK."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind((LOOPBACK, 0))
        port = probe.getsockname()[1]
    key = KEY if signed else None
    attitudes = _attitudes(n + 1, key)
    setpoint = _setpoint()
    async with guarded_port(LOOPBACK, port, system_id=1, signing_key=key) as guard:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as autopilot, \
                socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as mavsdk:
            autopilot.bind((LOOPBACK, 0))
            mavsdk.bind((LOOPBACK, guard.mavsdk_port))
            for s in (autopilot, mavsdk):
                s.settimeout(2.0)
            autopilot.sendto(attitudes[0], (LOOPBACK, port))
            _, relay = mavsdk.recvfrom(65535)
            out, back = [], []
            for data in attitudes[1:]:
                t0 = time.perf_counter()
                mavsdk.sendto(setpoint, relay)
                autopilot.recvfrom(65535)
                t1 = time.perf_counter()
                autopilot.sendto(data, (LOOPBACK, port))
                mavsdk.recvfrom(65535)
                t2 = time.perf_counter()
                out.append(t1 - t0)
                back.append(t2 - t1)
    return statistics.median(out) * 1e6, statistics.median(back) * 1e6


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=9)
    ap.add_argument("--datagrams", type=int, default=2000)
    args = ap.parse_args(argv)
    print(machine_line(), flush=True)
    work: dict[bool, list[tuple[float, float]]] = {False: [], True: []}
    relay: dict[bool, list[tuple[float, float]]] = {False: [], True: []}
    for _ in range(args.repeat):
        for signed in (False, True):
            work[signed].append(_work_us(args.datagrams, signed))
            relay[signed].append(asyncio.run(_relay_us(args.datagrams // 4, signed)))
    print(f"link guard, us per datagram (median of {args.repeat} interleaved rounds; work: {args.datagrams} "
          f"datagrams a round, relay: {args.datagrams // 4} one at a time)")
    for name, table in (("work ", work), ("relay", relay)):
        for leg, label in ((0, "MAVSDK -> autopilot"), (1, "autopilot -> MAVSDK")):
            plain, signed = (statistics.median(r[leg] for r in table[s]) for s in (False, True))
            print(f"  {name} {label}: unsigned {plain:7.2f}   signed {signed:7.2f}   +{signed - plain:6.2f}")
    print(machine_line().replace("machine:", "at the end:"), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
