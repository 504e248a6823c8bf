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

ADSB_VEHICLE carries no time at all. Each one is stamped here with the vehicle's clock of the last
stamped frame (GLOBAL_POSITION_INT, ATTITUDE) the vehicle sent before it, on the same link: the
autopilot's time when it reported the traffic, to within one period of those streams. Stamped with
the newest attitude MAVSDK delivered instead, a report read on a loaded machine was up to 2 s of
sim (at 20x) away from when it was sent, 8 m along a 4 m/s obstacle's path.
"""

from __future__ import annotations

import math
import struct
import threading
from collections import deque

from companion.vehicle.link_probe import mavlink_frames

ATTITUDE, GLOBAL_POSITION_INT, ADSB_VEHICLE = 30, 33, 246
_GPI = struct.Struct("<Iiiii")  # time_boot_ms, lat, lon, alt, relative_alt: the payload's first 20 bytes
_BOOT_MS = struct.Struct("<I")  # ATTITUDE's first field
_ADSB = struct.Struct("<Iii")  # ICAO_address, lat, lon: the payload's first 12 bytes
KEEP = 4096  # stamps kept: 40 s of wall time at the stub's 100/s cap, 20 s of PX4's 50 Hz at 4x

Key = tuple[int, int, int]  # lat 1e-7 deg, lon 1e-7 deg, relative altitude mm (traffic: ICAO, lat, lon)


def position_key(latitude_deg: float, longitude_deg: float, relative_altitude_m: float) -> Key:
    """The integers GLOBAL_POSITION_INT carried, from the floats MAVSDK made of them."""
    return round(latitude_deg * 1e7), round(longitude_deg * 1e7), round(relative_altitude_m * 1e3)


def _unpack(layout: struct.Struct, payload: bytes) -> tuple[int, ...]:
    # MAVLink 2 drops trailing zero bytes of a payload; they are zeros again here.
    return layout.unpack(payload[:layout.size].ljust(layout.size, b"\0"))


class _Sent:
    """Keys in the order sent, each with its stamp; a key is matched to the oldest unmatched one
    equal to it, later than the last match (MAVSDK hands messages over in order, and a vehicle
    standing still sends the same integers many times). The caller holds the lock."""

    def __init__(self, keep: int):
        self._sent: deque[tuple[Key, float]] = deque(maxlen=keep)
        self._last = -math.inf  # the stamp of the last match
        self.matched = self.missed = 0  # keys looked up, and found or not

    def append(self, key: Key, t_s: float) -> None:
        self._sent.append((key, t_s))

    def match(self, key: Key) -> float | None:
        while self._sent and self._sent[0][1] < self._last:
            self._sent.popleft()  # skipped by MAVSDK: never matched again
        for i, (sent, t_s) in enumerate(self._sent):
            if sent == key:
                del self._sent[i]
                self._last = t_s
                self.matched += 1
                return t_s
        self.missed += 1
        return None


class PositionStamps:
    """The last :data:`KEEP` positions and traffic reports of one system id with the vehicle's
    clock when it sent them, in the order sent; thread-safe (:meth:`record` runs on the link
    guard's thread, the lookups on the event loop)."""

    def __init__(self, system_id: int, keep: int = KEEP):
        self.system_id = system_id
        self._positions = _Sent(keep)
        self._traffic = _Sent(keep)
        self._clock_s: float | None = None  # the vehicle's clock in its last stamped frame
        self._lock = threading.Lock()

    @property
    def matched(self) -> int:
        return self._positions.matched

    @property
    def missed(self) -> int:
        return self._positions.missed

    @property
    def traffic_missed(self) -> int:
        return self._traffic.missed

    def record(self, datagram: bytes) -> None:
        """Note the stamp of every GLOBAL_POSITION_INT and ADSB_VEHICLE of our system id in
        ``datagram``, and the clock of its ATTITUDE."""
        for system_id, msgid, payload in mavlink_frames(datagram):
            if system_id != self.system_id:
                continue
            if msgid == GLOBAL_POSITION_INT:
                t_ms, lat, lon, _, rel_mm = _unpack(_GPI, payload)
                with self._lock:
                    self._positions.append((lat, lon, rel_mm), t_ms / 1e3)
                    self._clock_s = t_ms / 1e3
            elif msgid == ATTITUDE:
                self._clock_s = _unpack(_BOOT_MS, payload)[0] / 1e3
            elif msgid == ADSB_VEHICLE and self._clock_s is not None:
                icao, lat, lon = _unpack(_ADSB, payload)
                with self._lock:
                    self._traffic.append((icao, lat, lon), self._clock_s)

    def lookup(self, latitude_deg: float, longitude_deg: float, relative_altitude_m: float) -> float | None:
        """The vehicle's clock (s) when it sent this position, or None if it was not seen."""
        key = position_key(latitude_deg, longitude_deg, relative_altitude_m)
        with self._lock:
            return self._positions.match(key)

    def lookup_traffic(self, icao_address: int, latitude_deg: float, longitude_deg: float) -> float | None:
        """The vehicle's clock (s) when it sent this ADS-B report, or None if it was not seen."""
        key = (int(icao_address), round(latitude_deg * 1e7), round(longitude_deg * 1e7))
        with self._lock:
            return self._traffic.match(key)
