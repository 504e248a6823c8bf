"""The in-process link's telemetry side: the vehicle's messages folded into the port's board.

The MAVSDK adapter's telemetry pumps do the same from MAVSDK's streams: health from SYS_STATUS,
home and global position; a pose from each fresh (ATTITUDE, GLOBAL_POSITION_INT) pair, stamped
by the attitude's time; mode, armed and landed state; battery; ADS-B traffic in the mission frame.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Sequence
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from uav_model import frames
from companion.sitl.inprocess.link import MODES, text_field
from companion.vehicle.board import VehicleBoard
from companion.vehicle.convert import traffic_velocity_enu
from companion.vehicle.port import FlightMode, LandedState, TrafficReport
from sim_bridge.vehicle.px4 import Px4MainMode, decode_custom_mode

log = logging.getLogger(__name__)

SENSORS_REQUIRED = {  # MAVSDK's health_all_ok reads these SYS_STATUS bits
    "gyrometer": mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO,
    "accelerometer": mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL,
    "magnetometer": mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG,
    "gps": mavlink.MAV_SYS_STATUS_SENSOR_GPS,
}
LANDED = {
    mavlink.MAV_LANDED_STATE_ON_GROUND: LandedState.ON_GROUND, mavlink.MAV_LANDED_STATE_IN_AIR: LandedState.IN_AIR,
    mavlink.MAV_LANDED_STATE_TAKEOFF: LandedState.TAKING_OFF, mavlink.MAV_LANDED_STATE_LANDING: LandedState.LANDING,
}


def mode_of(custom_mode: int) -> FlightMode:
    main, sub = decode_custom_mode(custom_mode)
    return MODES.get((main, sub if main == Px4MainMode.AUTO else 0), FlightMode.OTHER)


class TelemetryIntake:
    """One vehicle's messages -> its :class:`VehicleBoard`; remembers what readiness still lacks."""

    def __init__(self, board: VehicleBoard, origin: frames.GeoOrigin, name: str):
        self._board = board
        self._origin = origin
        self._name = name
        self.sensors_ok = False
        self.home_seen = False
        self.position_seen = False
        self.param_types: dict[str, int] = {}  # PARAM_VALUE's type per name, as last heard
        # The pose's two halves, paired as the MAVSDK adapter pairs them (attitude stamp + position).
        self._att: tuple[float, float] | None = None  # (t_sim_s, heading_enu_rad)
        self._pos: tuple[float, float, float, float, float] | None = None  # x, y, alt, vx, vy
        self._att_fresh = False
        self._pos_fresh = False

    def missing(self) -> list[str]:
        """What keeps the vehicle from being ready (health all OK), as the MAVSDK adapter names it."""
        return [what for what, ok in (("sensors", self.sensors_ok), ("home position", self.home_seen),
                                      ("global position", self.position_seen)) if not ok]

    async def absorb(self, msgs: Sequence[Any]) -> None:
        """Fold a batch of the vehicle's messages into the board: one status update, one pose."""
        if not msgs:
            return
        board = self._board
        status = board.status()
        changes: dict[str, Any] = {}
        t_att: float | None = None
        adsb: list[Any] = []
        texts: list[str] = []
        for m in msgs:
            kind = m.get_type()
            if kind == "ATTITUDE":
                t_att = m.time_boot_ms / 1000.0
                self._att = (t_att, frames.ned_yaw_to_enu_heading(m.yaw))
                self._att_fresh = True
            elif kind == "GLOBAL_POSITION_INT":
                self.position_seen = True
                x, y, _ = frames.geodetic_to_local(self._origin, m.lat / 1e7, m.lon / 1e7)
                east, north, _ = frames.ned_to_enu(m.vx / 100.0, m.vy / 100.0, m.vz / 100.0)
                self._pos = (x, y, m.relative_alt / 1000.0, east, north)
                self._pos_fresh = True
            elif kind == "HEARTBEAT":
                changes["mode"] = mode_of(m.custom_mode)
                changes["armed"] = bool(m.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
            elif kind == "EXTENDED_SYS_STATE":
                changes["landed"] = LANDED.get(m.landed_state, LandedState.UNKNOWN)
            elif kind == "SYS_STATUS":
                need = sum(SENSORS_REQUIRED.values())
                self.sensors_ok = all(getattr(m, f) & need == need for f in (
                    "onboard_control_sensors_present", "onboard_control_sensors_enabled",
                    "onboard_control_sensors_health"))
            elif kind == "HOME_POSITION":
                self.home_seen = True
                changes["home_ok"] = True
            elif kind == "GPS_RAW_INT":
                changes["gps_fix_type"] = int(m.fix_type)
            elif kind == "PARAM_VALUE":
                self.param_types[text_field(m.param_id)] = int(m.param_type)
            elif kind == "BATTERY_STATUS":
                changes["battery_pct"] = float(m.battery_remaining) if m.battery_remaining >= 0 else None
            elif kind == "ADSB_VEHICLE":
                adsb.append(m)
            elif kind == "STATUSTEXT":
                log.info("%s: %s", self._name, text_field(m.text))
                texts.append(text_field(m.text))
        changes["health_ok"] = self.sensors_ok and self.home_seen and self.position_seen
        changes = {k: v for k, v in changes.items() if getattr(status, k) != v}
        if changes:
            await board.put_status(**changes)
        if t_att is not None:
            await board.note_clock(t_att)
        if self._att_fresh and self._pos_fresh and self._att is not None and self._pos is not None:
            self._att_fresh = self._pos_fresh = False
            x, y, alt, vx, vy = self._pos
            await board.put_pose(t_sim_s=self._att[0], x_east_m=x, y_north_m=y, alt_rel_m=alt,
                                 vx_east_m_s=vx, vy_north_m_s=vy, heading_enu_rad=self._att[1])
        for m in adsb:
            await self._traffic(m)
        for text in texts:
            await board.put_text(text)

    async def _traffic(self, m: Any) -> None:
        callsign = text_field(m.callsign)
        if not callsign or not m.flags & mavlink.ADSB_FLAGS_VALID_COORDS:
            return
        x, y, _ = frames.geodetic_to_local(self._origin, m.lat / 1e7, m.lon / 1e7)
        vx, vy = traffic_velocity_enu(m.heading / 100.0, m.hor_velocity / 100.0)
        t_sim = self._board.latest_clock_s if self._board.latest_clock_s is not None else math.nan
        await self._board.put_traffic(TrafficReport(callsign=callsign, x_east_m=x, y_north_m=y, vx_east_m_s=vx,
                                                    vy_north_m_s=vy, t_sim_s=t_sim,
                                                    t_wall_s=time.monotonic(), via=self._name))
