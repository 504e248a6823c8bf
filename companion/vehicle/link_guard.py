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

The relay runs on its own daemon thread, not on the companion's event loop: each datagram is
forwarded the moment it arrives, so a busy loop (a planner step, a load of 10 on the machine)
delays neither the vehicle's telemetry to MAVSDK nor MAVSDK's setpoints to the vehicle. The
thread waits on both sockets with a short timeout and a wake-up socket; leaving
:func:`guarded_port` stops it, waits (sleeping on the loop, never blocking it) until the thread
has ended, then closes the sockets, so the port is free again. The conflict event is set on the loop with ``call_soon_threadsafe``.
"""

from __future__ import annotations

import asyncio
import selectors
import socket
import threading
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from companion.errors import LinkConflict
from companion.vehicle.link_probe import frame_system_ids, probe_udpin, udpin_port
from companion.vehicle.position_stamps import PositionStamps

LOOPBACK = "127.0.0.1"
RELAY_BUFFER_BYTES = 4 << 20  # a burst (a parameter list at 20x) waits here while the process waits for a CPU
MAX_DATAGRAM = 65535
BURST = 64  # datagrams one side forwards before the other side's turn
POLL_S = 0.05  # the relay thread's longest wait: how soon it sees a stop without a wake-up
STOP_WAIT_S = 2.0  # how long leaving the guard waits for its thread


def _roomy(sock: socket.socket) -> socket.socket:
    """A receive buffer for bursts (SO_RCVBUFFORCE if allowed, else up to rmem_max)."""
    for option in (getattr(socket, "SO_RCVBUFFORCE", None), socket.SO_RCVBUF):
        if option is None:
            continue
        try:
            sock.setsockopt(socket.SOL_SOCKET, option, RELAY_BUFFER_BYTES)
            break
        except OSError:
            continue
    return sock


def _send(sock: socket.socket, data: bytes, addr: tuple[str, int]) -> None:
    try:
        sock.sendto(data, addr)
    except OSError:
        pass  # a full send buffer or ICMP port unreachable (a side not listening yet): UDP carries on


class LinkGuard:
    """Relay between the autopilot on ``outer`` and MAVSDK on ``mavsdk_port``; see the module docstring."""

    def __init__(self, system_id: int, mavsdk_port: int):
        self.system_id = system_id
        self.mavsdk_port = mavsdk_port
        self.autopilot: tuple[str, int] | None = None
        self.conflict: str | None = None
        self.conflicted = asyncio.Event()
        self.dropped = 0  # datagrams from a second source, never relayed
        self.relayed = 0  # datagrams forwarded either way
        self.stamps = PositionStamps(system_id)  # the autopilot's time of each position MAVSDK reads
        self._loop: asyncio.AbstractEventLoop | None = None
        self._outer: socket.socket | None = None
        self._inner: socket.socket | None = None
        self._stop = threading.Event()
        self._wake_r: socket.socket | None = None
        self._wake_w: socket.socket | None = None
        self._thread: threading.Thread | None = None

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
                self._signal_conflict()
            return
        if ours:
            self.stamps.record(data)
        if self._inner is not None:
            _send(self._inner, data, (LOOPBACK, self.mavsdk_port))
            self.relayed += 1

    def from_mavsdk(self, data: bytes, addr: tuple[str, int]) -> None:
        if addr[1] != self.mavsdk_port:
            return  # not MAVSDK: nobody else is told this private port
        if self.autopilot is not None and self._outer is not None:
            _send(self._outer, data, self.autopilot)
            self.relayed += 1

    def _signal_conflict(self) -> None:
        loop = self._loop
        if loop is None:
            self.conflicted.set()
            return
        try:
            loop.call_soon_threadsafe(self.conflicted.set)
        except RuntimeError:
            pass  # the loop has closed: nobody is left to tell

    def start(self, loop: asyncio.AbstractEventLoop, outer: socket.socket, inner: socket.socket) -> None:
        """Relay between ``outer`` and ``inner`` on a new daemon thread; the guard owns both sockets now."""
        self._loop, self._outer, self._inner = loop, outer, inner
        for sock in (outer, inner):
            sock.setblocking(False)
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._thread = threading.Thread(target=self._run, name=f"link-guard-{self.system_id}", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        sides = {self._outer: self.from_outside, self._inner: self.from_mavsdk}
        try:
            with selectors.DefaultSelector() as sel:
                for sock in (self._outer, self._inner, self._wake_r):
                    sel.register(sock, selectors.EVENT_READ)
                while not self._stop.is_set():
                    for key, _ in sel.select(POLL_S):
                        handle = sides.get(key.fileobj)
                        if handle is not None:
                            self._drain(key.fileobj, handle)
        except OSError:
            pass  # a socket closed under the selector: the guard is going away

    def _drain(self, sock: socket.socket, handle) -> None:
        """Forward the datagrams waiting on ``sock`` now (a burst at a time, so that the other side takes turns)."""
        for _ in range(BURST):
            try:
                data, addr = sock.recvfrom(MAX_DATAGRAM)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                continue  # an ICMP error queued on the socket: the next datagram may follow
            handle(data, (str(addr[0]), int(addr[1])))

    def close(self) -> None:
        """Ask the relay thread to stop; never blocks (:meth:`stopped` waits for it and frees the port)."""
        self._stop.set()
        if self._wake_w is not None and self._wake_w.fileno() != -1:
            try:
                self._wake_w.send(b"\0")
            except OSError:
                pass  # the wake-up is full: the thread has been told already

    def _close_sockets(self) -> None:
        for sock in (self._outer, self._inner, self._wake_r, self._wake_w):
            if sock is not None:
                sock.close()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    async def stopped(self, timeout_s: float = STOP_WAIT_S) -> None:
        """Stop the relay, wait on the loop (sleeping, never blocking) until its thread has ended,
        then close the sockets: the port is free when this returns."""
        self.close()
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        try:
            while self.running and loop.time() < deadline:
                await asyncio.sleep(0.005)
        finally:
            self._close_sockets()  # cancelled too: a thread still selecting sees them closed and ends


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
    guard = LinkGuard(system_id, _free_loopback_port())
    outer = _roomy(socket.socket(socket.AF_INET, socket.SOCK_DGRAM))
    try:
        outer.bind((host, port))
    except OSError as exc:
        outer.close()
        raise LinkConflict(f"cannot listen on udp {host}:{port}: {exc.strerror}", vehicle=vehicle) from None
    try:
        inner = _roomy(socket.socket(socket.AF_INET, socket.SOCK_DGRAM))
    except OSError:
        outer.close()
        raise
    try:
        inner.bind((LOOPBACK, 0))
        guard.start(asyncio.get_running_loop(), outer, inner)
    except BaseException:
        outer.close()
        inner.close()
        raise
    try:
        yield guard
    finally:
        await guard.stopped()
