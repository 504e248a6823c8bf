"""Who is sending to a ``udpin://`` port before MAVSDK opens it: one autopilot, or two answering
as the same system id (another SITL or stub already on the companion's port).

MAVSDK merges every sender with one system id into one system, silently: two autopilots on one
port become one vehicle whose telemetry jumps between them. So the port is listened to for a
moment first, and each MAVLink datagram's sender address is recorded per system id.
"""

from __future__ import annotations

import asyncio
import errno
import socket
from collections import defaultdict
from collections.abc import Iterator
from urllib.parse import urlparse

from companion.errors import LinkConflict
from uav_model.signing_key import SIGNATURE_BYTES

PROBE_S = 0.6  # wall; PX4 streams ATTITUDE at 100 Hz and the stub at 20 Hz: plenty of datagrams
MAVLINK_V1, MAVLINK_V2 = 0xFE, 0xFD
MAVLINK_IFLAG_SIGNED = 0x01


def frame_spans(datagram: bytes) -> list[tuple[int, int]]:
    """(start, end) of every MAVLink frame (v1 or v2) packed one after another in a datagram, as
    far as the headers can be followed; the last one may end past the datagram (truncated)."""
    spans: list[tuple[int, int]] = []
    i, n = 0, len(datagram)
    while i < n:
        if datagram[i] == MAVLINK_V2 and i + 10 <= n:
            signed = datagram[i + 2] & MAVLINK_IFLAG_SIGNED
            end = i + 12 + datagram[i + 1] + (SIGNATURE_BYTES if signed else 0)
        elif datagram[i] == MAVLINK_V1 and i + 6 <= n:
            end = i + 8 + datagram[i + 1]
        else:
            break  # not a frame start: the rest cannot be followed
        spans.append((i, end))
        i = end
    return spans


def mavlink_frames(datagram: bytes) -> Iterator[tuple[int, int, bytes]]:
    """``(system id, message id, payload)`` of every frame :func:`frame_spans` finds. A MAVLink 2
    payload comes as sent: trailing zero bytes truncated."""
    for i, _ in frame_spans(datagram):
        length = datagram[i + 1]
        if datagram[i] == MAVLINK_V2:
            msgid = datagram[i + 7] | datagram[i + 8] << 8 | datagram[i + 9] << 16
            yield datagram[i + 5], msgid, datagram[i + 10:i + 10 + length]
        else:
            yield datagram[i + 3], datagram[i + 5], datagram[i + 6:i + 6 + length]


def frame_system_ids(datagram: bytes) -> list[int]:
    """The system id of every MAVLink frame (v1 or v2) packed one after another in a datagram, as
    far as the headers can be followed (an autopilot may send several messages in one datagram)."""
    return [datagram[i + (5 if datagram[i] == MAVLINK_V2 else 3)] for i, _ in frame_spans(datagram)]


def sender_system_id(datagram: bytes) -> int | None:
    """The system id in the first MAVLink header of a datagram (v1 or v2), or None."""
    ids = frame_system_ids(datagram)
    return ids[0] if ids else None


def udpin_port(url: str) -> tuple[str, int] | None:
    parsed = urlparse(url)
    if parsed.scheme != "udpin" or parsed.port is None:
        return None
    return parsed.hostname or "0.0.0.0", parsed.port


class _Collector(asyncio.DatagramProtocol):
    def __init__(self) -> None:
        self.senders: dict[int, set[tuple[str, int]]] = defaultdict(set)

    def datagram_received(self, data: bytes, addr) -> None:
        sysid = sender_system_id(data)
        if sysid is not None:
            self.senders[sysid].add((str(addr[0]), int(addr[1])))


async def listen(host: str, port: int, seconds: float = PROBE_S) -> dict[int, set[tuple[str, int]]]:
    """Sender addresses per system id heard on a UDP port for ``seconds``; OSError if it is taken."""
    loop = asyncio.get_running_loop()
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.bind((host, port))
    except OSError:
        sock.close()
        raise
    transport, proto = await loop.create_datagram_endpoint(_Collector, sock=sock)
    try:
        await asyncio.sleep(seconds)
    finally:
        transport.close()
        await socket_closed(sock)
    return dict(proto.senders)


async def socket_closed(sock: socket.socket, turns: int = 10) -> None:
    """A closed transport closes its socket on a later loop turn: wait those turns, so that the
    port is free when the caller goes on."""
    for _ in range(turns):
        if sock.fileno() == -1:
            return
        await asyncio.sleep(0)


async def probe_udpin(url: str, system_id: int, vehicle: str, seconds: float = PROBE_S) -> None:
    """Refuse (LinkConflict) when two senders answer as ``system_id`` on a udpin URL, or the
    port is held by another program. Other URLs (udpout, tcp, serial) are not probed."""
    where = udpin_port(url)
    if where is None:
        return
    try:
        senders = await listen(*where, seconds)
    except OSError as exc:
        if exc.errno == errno.EADDRINUSE:
            raise LinkConflict(f"UDP port {where[1]} ({url}) is already taken by another program "
                               "(another companion or ground station?)", vehicle=vehicle) from None
        raise LinkConflict(f"cannot listen on {url}: {exc.strerror}", vehicle=vehicle) from None
    same = sorted(senders.get(system_id, ()))
    if len(same) > 1:
        addrs = ", ".join(f"{h}:{p}" for h, p in same)
        raise LinkConflict(f"{len(same)} autopilots answer as system {system_id} on {url} (from {addrs}); "
                           "stop the other one or give each its own port", vehicle=vehicle)
