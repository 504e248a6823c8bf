"""The vehicle's own time stamp for each position MAVSDK hands over.

MAVSDK's ``Position`` carries no time, although the GLOBAL_POSITION_INT it comes from does
(``time_boot_ms``). Paired with the newest attitude's stamp instead, a position read after a stall
(a load of 8, sixteen vehicles on two cores) is placed up to a second away from when it was
measured: at 10 m/s, tracks 10 m off along the route, implied speeds of 50 m/s between two samples,
and a separation "lost" that the vehicles never lost.

The link guard sees every datagram before MAVSDK does. It records each GLOBAL_POSITION_INT of the
vehicle's system id here (its thread); the position pump (the event loop) looks the stamp up by the
position's own integers (1e-7 degrees and millimetres are what MAVSDK scales to floats), so the
pair is exact. A position not found (no guard on the link, or evicted) keeps the attitude pairing.
"""

from __future__ import annotations

import math
import struct
import threading
from collections import deque

from companion.vehicle.link_probe import mavlink_frames

GLOBAL_POSITION_INT = 33
_GPI = struct.Struct("<Iiiii")  # time_boot_ms, lat, lon, alt, relative_alt: the payload's first 20 bytes
KEEP = 4096  # stamps kept: 40 s of wall time at the stub's 100/s cap, 20 s of PX4's 50 Hz at 4x

Key = tuple[int, int, int]  # lat 1e-7 deg, lon 1e-7 deg, relative altitude mm


def position_key(latitude_deg: float, longitude_deg: float, relative_altitude_m: float) -> Key:
    """The integers GLOBAL_POSITION_INT carried, from the floats MAVSDK made of them."""
    return round(latitude_deg * 1e7), round(longitude_deg * 1e7), round(relative_altitude_m * 1e3)


class PositionStamps:
    """The last :data:`KEEP` positions of one system id with their ``time_boot_ms``, in the order
    sent; thread-safe. A position is matched to the oldest unmatched one with the same integers,
    later than the last match: MAVSDK hands positions over in order, and a vehicle standing still
    sends the same integers many times."""

    def __init__(self, system_id: int, keep: int = KEEP):
        self.system_id = system_id
        self._sent: deque[tuple[Key, float]] = deque(maxlen=keep)
        self._last = -math.inf  # the stamp of the last match
        self.matched = self.missed = 0  # positions looked up, and found or not
        self._lock = threading.Lock()

    def record(self, datagram: bytes) -> None:
        """Note the stamp of every GLOBAL_POSITION_INT of our system id in ``datagram``."""
        for system_id, msgid, payload in mavlink_frames(datagram):
            if msgid != GLOBAL_POSITION_INT or system_id != self.system_id:
                continue
            # MAVLink 2 drops trailing zero bytes of a payload; they are zeros again here.
            t_ms, lat, lon, _, rel_mm = _GPI.unpack(payload[:_GPI.size].ljust(_GPI.size, b"\0"))
            with self._lock:
                self._sent.append(((lat, lon, rel_mm), t_ms / 1e3))

    def lookup(self, latitude_deg: float, longitude_deg: float, relative_altitude_m: float) -> float | None:
        """The vehicle's clock (s) when it sent this position, or None if it was not seen."""
        key = position_key(latitude_deg, longitude_deg, relative_altitude_m)
        with self._lock:
            while self._sent and self._sent[0][1] <= self._last:
                self._sent.popleft()  # matched, or skipped by MAVSDK: never matched again
            for i, (sent, t_s) in enumerate(self._sent):
                if sent == key:
                    del self._sent[i]
                    self._last = t_s
                    self.matched += 1
                    return t_s
            self.missed += 1
        return None
