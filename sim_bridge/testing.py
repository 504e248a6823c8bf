"""Helpers for tests and embedders: free UDP ports and a stub on them.

    async with stub_on_free_ports(mission, speedup=10) as sim:
        url = sim_connection_url(sim, 0)       # "udpin://0.0.0.0:<port>" for MAVSDK
"""

from __future__ import annotations

import contextlib
import socket
from collections.abc import AsyncIterator
from dataclasses import replace

from companion.mission import Mission
from sim_bridge.bridge import SimBridge, SimOptions


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


def sim_connection_url(sim: SimBridge, index: int) -> str:
    """The MAVSDK connection URL on which vehicle ``index`` of a running stub talks."""
    return f"udpin://0.0.0.0:{sim.options.api_port(index)}"


@contextlib.asynccontextmanager
async def stub_on_free_ports(mission: Mission, options: SimOptions | None = None, *, gcs: bool = True,
                             **overrides: object) -> AsyncIterator[SimBridge]:
    """A running stub whose API (and GCS) links point at freshly chosen free ports."""
    ports = free_udp_ports(len(mission.vehicles) + 1)
    base = options or SimOptions()
    opts = replace(base, api_ports=ports[:-1], gcs_port=ports[-1] if gcs else None, **overrides)
    async with SimBridge(mission, opts) as sim:
        yield sim


class GcsCodec:
    """Packs messages as a GCS would and parses them back, for driving a SimVehicle without sockets.

    The parsed copy has a real header (source system and component), exactly as a message that
    arrived on a link.
    """

    def __init__(self, system_id: int = 245, component_id: int = 190):
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
