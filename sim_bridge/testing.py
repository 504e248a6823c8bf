"""Helpers for tests and embedders: free UDP ports and a stub on them.

    async with stub_on_free_ports(mission, speedup=10) as sim:
        url = sim_connection_url(sim, 0)       # "udpin://0.0.0.0:<port>" for MAVSDK
"""

from __future__ import annotations

import contextlib
import socket
from collections.abc import AsyncIterator
from dataclasses import replace

from uav_model.mission import Mission
from sim_bridge.bridge import SimBridge, SimOptions
from sim_bridge.vehicle.px4 import COMPANION_SYSTEM_ID, GCS_COMPONENT_ID


def free_udp_ports(n: int) -> tuple[int, ...]:
    """``n`` distinct UDP ports free on all interfaces right now (held together while chosen)."""
    socks = []
    try:
        for _ in range(n):
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            s.bind(("0.0.0.0", 0))
            socks.append(s)
        return tuple(s.getsockname()[1] for s in socks)
    finally:
        for s in socks:
            s.close()


def bind_udp_port_block(count: int, host: str = "127.0.0.1", attempts: int = 200) -> list[socket.socket]:
    """``count`` sockets bound to consecutive free UDP ports (vehicle i talks to base + i).

    The caller holds them until the ports are handed over, so nothing else can take them.
    """
    for _ in range(attempts):
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            probe.bind((host, 0))
            base = probe.getsockname()[1]
        if base + count > 65535:
            continue
        socks: list[socket.socket] = []
        try:
            for port in range(base, base + count):
                s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                socks.append(s)
                s.bind((host, port))
            return socks
        except OSError:
            for s in socks:
                s.close()
    raise RuntimeError(f"no block of {count} free UDP ports found")


def free_udp_port_block(n: int, host: str = "127.0.0.1") -> int:
    """A base port with ``n`` consecutive free UDP ports (for ``--api-port-base``)."""
    socks = bind_udp_port_block(n, host)
    base = socks[0].getsockname()[1]
    for s in socks:
        s.close()
    return base


def sim_connection_url(sim: SimBridge, index: int) -> str:
    """The MAVSDK connection URL on which vehicle ``index`` of a running stub talks."""
    return f"udpin://0.0.0.0:{sim.options.api_port(index)}"


@contextlib.asynccontextmanager
async def stub_on_free_ports(mission: Mission, options: SimOptions | None = None, *, gcs: bool = True,
                             booted: bool = True, **overrides: object) -> AsyncIterator[SimBridge]:
    """A running stub whose API (and GCS) links point at freshly chosen free ports; with ``booted``,
    yielded once every vehicle passes its preflight checks (as a PX4 SITL started beforehand)."""
    ports = free_udp_ports(len(mission.vehicles) + 1)
    base = options or SimOptions()
    opts = replace(base, api_ports=ports[:-1], gcs_port=ports[-1] if gcs else None, **overrides)
    async with SimBridge(mission, opts) as sim:
        if booted:
            await sim.wait_for(lambda: all(v.modes.healthy() for v in sim.vehicles), timeout_s=60.0)
        yield sim


class GcsCodec:
    """Packs messages as a GCS would and parses them back, for driving a SimVehicle without sockets.

    The parsed copy has a real header (source system and component), exactly as a message that
    arrived on a link.
    """

    def __init__(self, system_id: int = COMPANION_SYSTEM_ID, component_id: int = GCS_COMPONENT_ID):
        from pymavlink.dialects.v20 import common as mavlink

        self.enc = mavlink.MAVLink(None, system_id, component_id)
        self._dec = mavlink.MAVLink(None, 0, 0)

    def wire(self, msg):
        buf = msg.pack(self.enc)
        self.enc.seq = (self.enc.seq + 1) % 256
        (out,) = self._dec.parse_buffer(buf)
        return out

    def command(self, command: int, *params: float, target: int = 1, component: int = 1):
        """A COMMAND_LONG; missing params are 0."""
        p = list(params) + [0.0] * (7 - len(params))
        return self.wire(self.enc.command_long_encode(target, component, command, 0, *p))


_INT_RANGES = {
    "uint8_t": (0, 2**8 - 1), "int8_t": (-(2**7), 2**7 - 1), "uint16_t": (0, 2**16 - 1),
    "int16_t": (-(2**15), 2**15 - 1), "uint32_t": (0, 2**32 - 1), "int32_t": (-(2**31), 2**31 - 1),
    "uint64_t": (0, 2**64 - 1), "int64_t": (-(2**63), 2**63 - 1),
}
_NASTY_FLOATS = (float("nan"), float("inf"), float("-inf"), 0.0, -0.0, 1e38, -1e38, 1e-45)


def random_message(rng, *, target_system: int | None = None, message_ids=None):
    """A well-formed message of a random common-dialect type with random (often hostile) fields.

    Floats are often NaN or infinite, integers span their whole range, targets are usually
    0, 1 or 2 (so that many messages reach a vehicle) unless ``target_system`` fixes them.
    """
    from pymavlink.dialects.v20 import common as mavlink

    ids = sorted(mavlink.mavlink_map) if message_ids is None else list(message_ids)
    cls = mavlink.mavlink_map[rng.choice(ids)]
    values = []
    for name, ftype in zip(cls.fieldnames, cls.fieldtypes):
        length = cls.array_lengths[cls.ordered_fieldnames.index(name)]
        if ftype == "char":
            n = rng.randint(0, max(1, length))
            values.append(bytes(rng.randint(32, 126) for _ in range(n)))
            continue

        def one() -> float | int:
            if ftype in ("float", "double"):
                return rng.choice(_NASTY_FLOATS) if rng.random() < 0.3 else rng.uniform(-1e4, 1e4)
            lo, hi = _INT_RANGES[ftype]
            if name == "target_system":
                return target_system if target_system is not None else rng.choice((0, 1, 2, rng.randint(lo, hi)))
            if name == "target_component":
                return rng.choice((0, 1, rng.randint(lo, hi)))
            return rng.choice((lo, hi, 0, 1, rng.randint(lo, hi), rng.randint(0, min(hi, 600))))

        values.append([one() for _ in range(length)] if length else one())
    return cls(*values)


# ---------------------------------------------------------------- driving a SimVehicle -------
SIM_DT_S = 0.02  # the bridge's default physics step


def step_for(v, seconds: float, until=None, dt_s: float = SIM_DT_S) -> list:
    """Step ``v`` for ``seconds`` of sim time (or until ``until(v)``); every message emitted."""
    out = []
    for _ in range(int(round(seconds / dt_s))):
        out += [e.msg for e in v.step(dt_s)]
        if until is not None and until(v):
            break
    return out


def ack_of(emits, command: int):
    """The one COMMAND_ACK for ``command`` among ``emits``."""
    acks = [e.msg for e in emits if e.msg.get_type() == "COMMAND_ACK" and e.msg.command == command]
    assert len(acks) == 1, emits
    return acks[0]


def send_command(v, gcs: GcsCodec, command: int, *params: float, target: int = 1):
    """Send a COMMAND_LONG to ``v`` over the "api" link; its COMMAND_ACK."""
    return ack_of(v.handle(gcs.command(command, *params, target=target), "api"), command)


def boot(v) -> list:
    """Step ``v`` until its preflight checks pass (PX4 refuses to arm for the first seconds)."""
    return step_for(v, 30.0, until=lambda v: v.modes.healthy())


def upload_waypoints(v, gcs: GcsCodec, mission: Mission, waypoints_enu_m) -> None:
    """Upload NAV_WAYPOINTs (mission ENU x, y, alt above home) to ``v`` through its mission protocol."""
    from pymavlink.dialects.v20 import common as mavlink

    from uav_model.frames import local_to_geodetic

    n = len(waypoints_enu_m)
    v.handle(gcs.wire(gcs.enc.mission_count_encode(v.system_id, 1, n, mavlink.MAV_MISSION_TYPE_MISSION)), "api")
    for seq, (x, y, alt) in enumerate(waypoints_enu_m):
        lat, lon, _ = local_to_geodetic(mission.origin, x, y)
        v.handle(gcs.wire(gcs.enc.mission_item_int_encode(
            v.system_id, 1, seq, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, mavlink.MAV_CMD_NAV_WAYPOINT,
            1 if seq == 0 else 0, 1, 0.0, 0.0, 0.0, float("nan"), int(round(lat * 1e7)), int(round(lon * 1e7)),
            alt, mavlink.MAV_MISSION_TYPE_MISSION)), "api")
    assert len(v.missions.plan()) == n
