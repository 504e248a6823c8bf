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

Setpoints are a stream in which only the newest counts: when several SET_POSITION_TARGET_* or
SET_ATTITUDE_TARGET frames from MAVSDK for one target wait in the guard's socket at once (the
process lost the CPU for a while), only the newest of them is forwarded, in its place; every
other datagram is forwarded in order. Counted in :attr:`LinkGuard.stale_setpoints`.

With a signing key (``companion run --signing-key``), the guard signs what MAVSDK sends and
drops what the autopilot sends unsigned or signed with another key
(:mod:`companion.vehicle.link_signing`); only a correctly signed frame makes an address the
vehicle's autopilot. Before the autopilot has sent one good frame, a refused frame from its
system id, with no good one for a second after it, means the two sides disagree about signing:
:meth:`LinkGuard.first_word` raises it (:attr:`LinkGuard.signing_problem` says how) before
MAVSDK waits in vain. Without a key, an autopilot that signs is the same disagreement (it would
refuse every unsigned command).
"""

from __future__ import annotations

import asyncio
import selectors
import socket
import threading
import time
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from pymavlink.dialects.v20 import common as mavlink

from companion.errors import LinkConflict, SigningRefused
from companion.vehicle.link_probe import (MAVLINK_IFLAG_SIGNED, MAVLINK_V2, frame_spans, frame_system_ids,
                                          probe_udpin, udpin_port)
from companion.vehicle.link_signing import LinkSigner, Refusal
from companion.vehicle.position_stamps import PositionStamps

LOOPBACK = "127.0.0.1"
RELAY_BUFFER_BYTES = 4 << 20  # a burst (a parameter list at 20x) waits here while the process waits for a CPU
MAX_DATAGRAM = 65535
BURST = 64  # datagrams one side forwards before the other side's turn
POLL_S = 0.05  # the relay thread's longest wait: how soon it sees a stop without a wake-up
STOP_WAIT_S = 2.0  # how long leaving the guard waits for its thread
FIRST_WORD_POLL_S = 0.01
SIGNING_GRACE_S = 1.0  # wall: how long refused frames may go without one good frame before it is a disagreement
SETPOINT_IDS = frozenset({mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED,
                          mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_GLOBAL_INT,
                          mavlink.MAVLINK_MSG_ID_SET_ATTITUDE_TARGET})


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

    def __init__(self, system_id: int, mavsdk_port: int, signing_key: bytes | None = None):
        self.system_id = system_id
        self.mavsdk_port = mavsdk_port
        self.autopilot: tuple[str, int] | None = None
        self.conflict: str | None = None
        self.conflicted = asyncio.Event()
        self.signing_problem: str | None = None
        self._suspect: tuple[str, float] | None = None  # the first refused frame of the system id: why, when
        self.signer = None if signing_key is None else LinkSigner(signing_key)
        self.dropped = 0  # datagrams from a second source, never relayed
        self.relayed = 0  # datagrams forwarded either way
        self.stamps = PositionStamps(system_id)  # the autopilot's time of each position MAVSDK reads
        self.heard = False  # a frame from outside has been relayed to MAVSDK (with a key: a correctly signed one)
        self.stale_setpoints = 0  # setpoints from MAVSDK overtaken by a newer one while queued
        self._decoder = mavlink.MAVLink(None)  # reads a setpoint's target (the relay thread's own)
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
        if self.signer is not None:
            data, signers, refused = self.signer.check(data)
            if refused:
                self._refused(refused, addr)
            ours = self.system_id in signers
            self.heard = self.heard or bool(signers)
            if not data:
                return
        else:
            ours = self.system_id in frame_system_ids(data)
            if ours and self.signing_problem is None and self.autopilot in (None, addr) and self._signed(data):
                self.signing_problem = (f"signing: the autopilot (system {self.system_id} at {addr[0]}:{addr[1]}) "
                                        "signs its MAVLink frames and so refuses unsigned commands; give the "
                                        "companion its key with --signing-key FILE")
        if ours and self.autopilot is None:
            self.autopilot = addr
        if ours and addr != self.autopilot:
            self.dropped += 1
            if self.conflict is None:
                a = self.autopilot
                self.conflict = (f"link conflict: system id {self.system_id} from two sources "
                                 f"{a[0]}:{a[1]} and {addr[0]}:{addr[1]}")
                self._signal(self.conflicted)
            return
        if ours:
            self.stamps.record(data)
        if self._inner is not None:
            _send(self._inner, data, (LOOPBACK, self.mavsdk_port))
            self.relayed += 1
            self.heard = self.heard or self.signer is None

    def _signed(self, data: bytes) -> bool:
        return any(data[i] == MAVLINK_V2 and data[i + 5] == self.system_id and data[i + 2] & MAVLINK_IFLAG_SIGNED
                   for i, _ in frame_spans(data))

    def _refused(self, refused: list[Refusal], addr: tuple[str, int]) -> None:
        """Frames the signing check dropped (counted by the signer): before the autopilot's first
        good frame, a suspected disagreement about signing (or a forger: see :meth:`first_word`)."""
        if self.autopilot is not None or self._suspect is not None:
            return
        mine = [r for r in refused if r.system_id == self.system_id]
        if not mine:
            return
        where = f"system {self.system_id} at {addr[0]}:{addr[1]}"
        if any(r.signed for r in mine):
            why = f"frames from {where} fail the signature check: the autopilot's key is not the one in --signing-key"
        else:
            why = (f"the autopilot ({where}) sends unsigned MAVLink frames but --signing-key is set: give the "
                   "autopilot the same key, or fly without --signing-key")
        self._suspect = f"signing: {why}", time.monotonic()

    def from_mavsdk(self, data: bytes, addr: tuple[str, int]) -> None:
        if addr[1] != self.mavsdk_port:
            return  # not MAVSDK: nobody else is told this private port
        if self.signer is not None and self.autopilot is not None:
            data = self.signer.sign(data)
            if not data:
                return
        if self.autopilot is not None and self._outer is not None:
            _send(self._outer, data, self.autopilot)
            self.relayed += 1

    def _signal(self, event: asyncio.Event) -> None:
        loop = self._loop
        if loop is None:
            event.set()
            return
        try:
            loop.call_soon_threadsafe(event.set)
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
        """Forward the datagrams waiting on ``sock`` now (a burst at a time, so that the other side
        takes turns); of MAVSDK's setpoints for one target in a burst, only the newest."""
        burst: list[tuple[bytes, tuple[str, int]]] = []
        for _ in range(BURST):
            try:
                data, addr = sock.recvfrom(MAX_DATAGRAM)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                continue  # an ICMP error queued on the socket: the next datagram may follow
            burst.append((data, (str(addr[0]), int(addr[1]))))
        if sock is self._inner and len(burst) > 1:
            burst = self._newest_setpoints(burst)
        for data, addr in burst:
            handle(data, addr)

    def _setpoint_target(self, data: bytes) -> tuple[int, ...] | None:
        """(message, sender, target) when ``data`` is one setpoint frame, else None."""
        spans = frame_spans(data)
        if len(spans) != 1 or data[0] != MAVLINK_V2 or len(data) < 10:
            return None
        msg_id = data[7] | data[8] << 8 | data[9] << 16
        if msg_id not in SETPOINT_IDS:
            return None
        try:
            msg = self._decoder.decode(bytearray(data))
        except Exception:  # noqa: BLE001 - pymavlink raises several kinds on a bad frame: forward it as it is
            return None
        return msg_id, data[5], data[6], msg.target_system, msg.target_component

    def _newest_setpoints(self, burst: list[tuple[bytes, tuple[str, int]]]) -> list[tuple[bytes, tuple[str, int]]]:
        targets = [self._setpoint_target(data) for data, _ in burst]
        newest = {t: i for i, t in enumerate(targets) if t is not None}
        kept = [item for i, (item, t) in enumerate(zip(burst, targets)) if t is None or newest[t] == i]
        self.stale_setpoints += len(burst) - len(kept)
        return kept

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

    def link_events(self) -> dict[str, int]:
        """What the guard kept from the vehicle's link, for the run's summary (nonzero counts only)."""
        events = {"second_source_dropped": self.dropped, "stale_setpoints_dropped": self.stale_setpoints,
                  "positions_unstamped": self.stamps.missed, "traffic_unstamped": self.stamps.traffic_missed}
        if self.signer is not None:
            events.update(signed_out=self.signer.signed, upgraded_to_mavlink2=self.signer.upgraded,
                          unsignable_dropped=self.signer.unsignable, verified_in=self.signer.verified,
                          signing_refused=self.signer.refused)
        return {k: v for k, v in events.items() if v}

    async def first_word(self, timeout_s: float, vehicle: str | None = None) -> bool:
        """Wait until a frame from outside has passed to MAVSDK (with a key: a correctly signed one):
        True; False after ``timeout_s`` of silence. SigningRefused when the two sides disagree
        about signing: refused frames of the system id and, for SIGNING_GRACE_S after the first,
        not one good frame (an autopilot streams; a forger's frames are followed by the real
        autopilot's)."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        while not self.heard and self.signing_problem is None and loop.time() < deadline:
            suspect = self._suspect
            if suspect is not None and time.monotonic() - suspect[1] > SIGNING_GRACE_S:
                self.signing_problem = suspect[0]
                break
            await asyncio.sleep(FIRST_WORD_POLL_S)
        if self.signing_problem is not None:
            raise SigningRefused(self.signing_problem, vehicle=vehicle)
        return self.heard

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
async def guarded_link(url: str, system_id: int, vehicle: str,
                       signing_key: bytes | None = None) -> AsyncIterator[tuple[str, LinkGuard | None]]:
    """The URL MAVSDK should open for ``url`` and its guard, while the context is open: a
    ``udpin://`` port is probed (two autopilots already: LinkConflict), then held by a guard;
    other URLs (udpout, tcp, serial) are MAVSDK's own, unguarded, and cannot be signed."""
    where = udpin_port(url)
    if where is None and signing_key is not None:
        raise SigningRefused(f"signing: {url} is not a udpin:// link; the companion signs only on the UDP "
                             "ports it holds", vehicle=vehicle)
    await probe_udpin(url, system_id, vehicle)
    if where is None:
        yield url, None
        return
    async with guarded_port(*where, system_id, vehicle, signing_key=signing_key) as guard:
        yield guard.mavsdk_url, guard


@asynccontextmanager
async def guarded_port(host: str, port: int, system_id: int, vehicle: str | None = None, *,
                       signing_key: bytes | None = None) -> AsyncIterator[LinkGuard]:
    """Hold ``host:port`` for the vehicle while the context is open (LinkConflict if it is taken)."""
    guard = LinkGuard(system_id, _free_loopback_port(), signing_key)
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
