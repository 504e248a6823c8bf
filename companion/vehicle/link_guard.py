"""A vehicle's ``udpin://`` port held by the companion, so that a second sender is seen in flight.

MAVSDK hides where a datagram came from and merges every sender that uses one system id into one
vehicle: a spoofed HEARTBEAT from another UDP source reads as a mode change, spoofed positions as
a flown path. The pre-flight probe (:mod:`companion.vehicle.link_probe`) catches two sources
before the flight; this guard keeps watching during it. It binds the user's port itself and
relays datagrams to and from MAVSDK, which listens on a private loopback port:

    autopilot  <->  HOST:PORT (the guard)  <->  127.0.0.1:Q (MAVSDK, udpin)

The first sender that speaks as the vehicle's system id is its autopilot. A frame with that
system id from any other address is never relayed; the guard records a :attr:`LinkGuard.conflict`
("link conflict: system id N from two sources A and B") and sets :attr:`LinkGuard.conflicted`,
which the adapter turns into the vehicle's status. Datagrams of other system ids are relayed as
before. MAVSDK's replies go to the vehicle's autopilot only.
"""

from __future__ import annotations

import asyncio
import socket
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from companion.errors import LinkConflict
from companion.vehicle.link_probe import frame_system_ids, probe_udpin, socket_closed, udpin_port

LOOPBACK = "127.0.0.1"
RELAY_BUFFER_BYTES = 4 << 20  # a burst (a parameter list at 20x) waits here while the event loop is busy


def _roomy(sock: socket.socket) -> socket.socket:
    """A receive buffer that rides out a busy event loop (SO_RCVBUFFORCE if allowed, else up to rmem_max)."""
    for option in (getattr(socket, "SO_RCVBUFFORCE", None), socket.SO_RCVBUF):
        if option is None:
            continue
        try:
            sock.setsockopt(socket.SOL_SOCKET, option, RELAY_BUFFER_BYTES)
            break
        except OSError:
            continue
    return sock


class _Side(asyncio.DatagramProtocol):
    def __init__(self, on_datagram) -> None:
        self.on_datagram = on_datagram
        self.transport: asyncio.DatagramTransport | None = None

    def connection_made(self, transport) -> None:
        self.transport = transport

    def datagram_received(self, data: bytes, addr) -> None:
        self.on_datagram(data, (str(addr[0]), int(addr[1])))

    def error_received(self, exc: Exception) -> None:
        pass  # ICMP port unreachable while a side is not listening yet: UDP carries on


class LinkGuard:
    """Relay between the autopilot on ``outer`` and MAVSDK on ``mavsdk_port``; see the module docstring."""

    def __init__(self, system_id: int, mavsdk_port: int):
        self.system_id = system_id
        self.mavsdk_port = mavsdk_port
        self.autopilot: tuple[str, int] | None = None
        self.conflict: str | None = None
        self.conflicted = asyncio.Event()
        self.dropped = 0  # datagrams from a second source, never relayed
        self._outer: _Side | None = None
        self._inner: _Side | None = None
        self._mavsdk: tuple[str, int] | None = None

    @property
    def mavsdk_url(self) -> str:
        return f"udpin://{LOOPBACK}:{self.mavsdk_port}"

    def from_outside(self, data: bytes, addr: tuple[str, int]) -> None:
        ours = self.system_id in frame_system_ids(data)
        if ours and self.autopilot is None:
            self.autopilot = addr
        if ours and addr != self.autopilot:
            self.dropped += 1
            if self.conflict is None:
                a = self.autopilot
                self.conflict = (f"link conflict: system id {self.system_id} from two sources "
                                 f"{a[0]}:{a[1]} and {addr[0]}:{addr[1]}")
                self.conflicted.set()
            return
        if self._inner is not None and self._inner.transport is not None:
            self._inner.transport.sendto(data, (LOOPBACK, self.mavsdk_port))

    def from_mavsdk(self, data: bytes, addr: tuple[str, int]) -> None:
        if addr[1] != self.mavsdk_port:
            return  # not MAVSDK: nobody else is told this private port
        if self.autopilot is not None and self._outer is not None and self._outer.transport is not None:
            self._outer.transport.sendto(data, self.autopilot)

    def close(self) -> None:
        for side in (self._outer, self._inner):
            if side is not None and side.transport is not None:
                side.transport.close()


def _free_loopback_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((LOOPBACK, 0))
        return int(s.getsockname()[1])


@asynccontextmanager
async def guarded_link(url: str, system_id: int, vehicle: str) -> AsyncIterator[tuple[str, LinkGuard | None]]:
    """The URL MAVSDK should open for ``url`` and its guard, while the context is open: a
    ``udpin://`` port is probed (two autopilots already: LinkConflict), then held by a guard;
    other URLs (udpout, tcp, serial) are MAVSDK's own, unguarded."""
    await probe_udpin(url, system_id, vehicle)
    where = udpin_port(url)
    if where is None:
        yield url, None
        return
    async with guarded_port(*where, system_id, vehicle) as guard:
        yield guard.mavsdk_url, guard


@asynccontextmanager
async def guarded_port(host: str, port: int, system_id: int, vehicle: str | None = None) -> AsyncIterator[LinkGuard]:
    """Hold ``host:port`` for the vehicle while the context is open (LinkConflict if it is taken)."""
    loop = asyncio.get_running_loop()
    guard = LinkGuard(system_id, _free_loopback_port())
    outer = _roomy(socket.socket(socket.AF_INET, socket.SOCK_DGRAM))
    try:
        outer.bind((host, port))
    except OSError as exc:
        outer.close()
        raise LinkConflict(f"cannot listen on udp {host}:{port}: {exc.strerror}", vehicle=vehicle) from None
    try:
        _, guard._outer = await loop.create_datagram_endpoint(lambda: _Side(guard.from_outside), sock=outer)
        inner = _roomy(socket.socket(socket.AF_INET, socket.SOCK_DGRAM))
        inner.bind((LOOPBACK, 0))
        _, guard._inner = await loop.create_datagram_endpoint(lambda: _Side(guard.from_mavsdk), sock=inner)
        yield guard
    finally:
        guard.close()
        await socket_closed(outer)
