"""Telemetry stream scheduling, one scheduler per (vehicle, link). Pure.

Stream rates are in *sim* time, as in PX4 SITL with lockstep: a 20 Hz stream gives 20 samples
per simulated second at any speed factor, so a planner ticking in sim time sees the same data
density at 1x and at 20x. Two wall-clock rules sit on top:

- every stream is capped at ``max_wall_rate_hz`` of wall time, so a fast speed factor cannot
  flood a link (a GCS does not need 400 Hz positions);
- HEARTBEAT is also sent at ``heartbeat_min_wall_hz`` of wall time at least, because MAVSDK's
  connection timeouts run on the wall clock.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

from pymavlink.dialects.v20 import common as mavlink

HEARTBEAT_ID = mavlink.MAVLINK_MSG_ID_HEARTBEAT


def _rates(**by_name: float) -> Mapping[int, float]:
    return MappingProxyType({getattr(mavlink, f"MAVLINK_MSG_ID_{name}"): hz for name, hz in by_name.items()})


# Sim-time rates (Hz). The API link has PX4 SITL's onboard-link rates as measured on PX4 SIH
# (../shared/px4-sih/README.md: ATTITUDE 100, GLOBAL_POSITION_INT 50, LOCAL_POSITION_NED 30,
# SYS_STATUS 5, EXTENDED_SYS_STATE 5, GPS_RAW_INT 8); the GCS link only watches. ADSB_VEHICLE
# is the stub's own (PX4 SIH has no traffic): the companion's moving-obstacle feed.
API_RATES_HZ = _rates(HEARTBEAT=1.0, SYS_STATUS=5.0, EXTENDED_SYS_STATE=5.0, LOCAL_POSITION_NED=30.0,
                      GLOBAL_POSITION_INT=50.0, ATTITUDE=100.0, GPS_RAW_INT=8.0, HOME_POSITION=0.5,
                      BATTERY_STATUS=1.0, MISSION_CURRENT=1.0, ADSB_VEHICLE=4.0)
GCS_RATES_HZ = _rates(HEARTBEAT=1.0, SYS_STATUS=1.0, EXTENDED_SYS_STATE=1.0, LOCAL_POSITION_NED=4.0,
                      GLOBAL_POSITION_INT=4.0, ATTITUDE=4.0, GPS_RAW_INT=1.0, HOME_POSITION=0.5,
                      BATTERY_STATUS=0.5, MISSION_CURRENT=1.0, ADSB_VEHICLE=1.0)


@dataclass(frozen=True, slots=True)
class StreamProfile:
    """Default stream rates of one link kind."""

    rates_hz: Mapping[int, float] = field(default_factory=lambda: API_RATES_HZ)
    max_wall_rate_hz: float = 100.0
    heartbeat_min_wall_hz: float = 1.0


API_PROFILE = StreamProfile(API_RATES_HZ, max_wall_rate_hz=100.0)
GCS_PROFILE = StreamProfile(GCS_RATES_HZ, max_wall_rate_hz=10.0)


class StreamScheduler:
    """Decides which streamed messages are due on one link."""

    def __init__(self, profile: StreamProfile):
        self._profile = profile
        self._interval_s: dict[int, float] = {i: 1.0 / hz for i, hz in profile.rates_hz.items() if hz > 0}
        self._next_sim: dict[int, float] = {}
        self._next_wall: dict[int, float] = {}  # earliest wall time allowed by the cap
        self._last_wall: dict[int, float] = {}
        self._min_wall_gap_s = 1.0 / profile.max_wall_rate_hz if profile.max_wall_rate_hz > 0 else 0.0
        self._hb_wall_gap_s = 1.0 / profile.heartbeat_min_wall_hz

    def interval_s(self, msg_id: int) -> float | None:
        """The sim-time interval of a stream, or None when it is off."""
        return self._interval_s.get(msg_id)

    def default_interval_s(self, msg_id: int) -> float | None:
        hz = self._profile.rates_hz.get(msg_id, 0.0)
        return 1.0 / hz if hz > 0 else None

    def set_interval(self, msg_id: int, interval_s: float | None) -> None:
        """Set a stream's sim-time interval; None turns it off."""
        if interval_s is None:
            self._interval_s.pop(msg_id, None)
        else:
            self._interval_s[msg_id] = interval_s
        self._next_sim.pop(msg_id, None)
        self._next_wall.pop(msg_id, None)

    def reset_default(self, msg_id: int) -> None:
        self.set_interval(msg_id, self.default_interval_s(msg_id))

    def due(self, sim_t: float, wall_t: float) -> list[int]:
        """Message ids to send now; marks them sent."""
        out: list[int] = []
        gap = self._min_wall_gap_s
        for msg_id, interval in self._interval_s.items():
            nxt = self._next_sim.get(msg_id, sim_t)
            next_wall = self._next_wall.get(msg_id, wall_t)
            due = sim_t >= nxt and wall_t >= next_wall
            if msg_id == HEARTBEAT_ID and not due:
                last_wall = self._last_wall.get(msg_id)
                due = last_wall is None or wall_t - last_wall >= self._hb_wall_gap_s
            if due:
                out.append(msg_id)
                self._last_wall[msg_id] = wall_t
                # Keep the phase of both clocks; after falling a whole period behind (a slow
                # tick), restart it rather than send a burst.
                nxt += interval
                self._next_sim[msg_id] = nxt if nxt > sim_t else sim_t + interval
                next_wall += gap
                self._next_wall[msg_id] = next_wall if next_wall > wall_t else wall_t + gap
        if HEARTBEAT_ID not in self._interval_s:
            last_wall = self._last_wall.get(HEARTBEAT_ID)
            if last_wall is None or wall_t - last_wall >= self._hb_wall_gap_s:
                out.append(HEARTBEAT_ID)
                self._last_wall[HEARTBEAT_ID] = wall_t
        return out
