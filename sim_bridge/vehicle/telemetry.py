"""Telemetry: the streamed and requested messages a vehicle sends, built from its state."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Callable

from pymavlink.dialects.v20 import common as mavlink

from uav_model.frames import local_to_geodetic
from uav_model.plant import Plant
from uav_model.plant.multicopter import attitude
from sim_bridge.vehicle.health import sensor_bits
from sim_bridge.vehicle.mission_protocol import MISSION
from sim_bridge.vehicle.px4 import PX4_FLIGHT_SW_VERSION, FlightMode
from sim_bridge.vehicle.streams import API_PROFILE, StreamProfile, StreamScheduler
from sim_bridge.vehicle.types import Emit, clip

if TYPE_CHECKING:
    from sim_bridge.vehicle import SimVehicle


CAPABILITIES = (mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
                | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
                | mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE
                | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_RALLY)

ADSB_ICAO_BASE = 0xAD0000  # ICAO address of obstacle k (index in mission.world.obstacles) = base + k
ADSB_FLAGS = (mavlink.ADSB_FLAGS_VALID_COORDS | mavlink.ADSB_FLAGS_VALID_ALTITUDE | mavlink.ADSB_FLAGS_VALID_HEADING
              | mavlink.ADSB_FLAGS_VALID_VELOCITY | mavlink.ADSB_FLAGS_VALID_CALLSIGN | mavlink.ADSB_FLAGS_SIMULATED)


def _cm_s(v: float) -> int:
    return int(clip(round(v * 100.0), -32767, 32767))


class Telemetry:
    """Message builders by id, and the per-link stream schedulers that pace them."""

    def __init__(self, v: "SimVehicle"):
        self._v = v
        self._mav = v.mav
        self.links: dict[str, StreamScheduler] = {}
        self._geo_cache: tuple[int, tuple[float, float, float]] | None = None
        self.builders: dict[int, Callable[[], list[Any]]] = {
            mavlink.MAVLINK_MSG_ID_HEARTBEAT: lambda: [self.heartbeat()],
            mavlink.MAVLINK_MSG_ID_SYS_STATUS: lambda: [self.sys_status()],
            mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: lambda: [self.extended_sys_state()],
            mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: lambda: [self.local_position_ned()],
            mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: lambda: [self.global_position_int()],
            mavlink.MAVLINK_MSG_ID_ATTITUDE: lambda: [self.attitude()],
            mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: lambda: [self.gps_raw_int()],
            mavlink.MAVLINK_MSG_ID_HOME_POSITION: lambda: [self.home_position()],
            mavlink.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN: lambda: [self.gps_global_origin()],
            mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: lambda: [self.battery_status()],
            mavlink.MAVLINK_MSG_ID_MISSION_CURRENT: lambda: [self.mission_current()],
            mavlink.MAVLINK_MSG_ID_ADSB_VEHICLE: self.adsb_vehicles,
            mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION: lambda: [self.autopilot_version()],
        }

    def add_link(self, link: str, profile: StreamProfile = API_PROFILE) -> None:
        self.links[link] = StreamScheduler(profile)

    def due(self, wall_t: float) -> list[Emit]:
        """Streamed messages due now on every link."""
        out: list[Emit] = []
        for link, sched in self.links.items():
            for msg_id in sched.due(self._v.sim_time_s, wall_t):
                for m in self.builders[msg_id]():
                    out.append(Emit(m, link))
        return out

    def build(self, msg_id: int) -> list[Any]:
        builder = self.builders.get(msg_id)
        return builder() if builder else []

    @property
    def time_boot_ms(self) -> int:
        return int(self._v.sim_time_s * 1000.0) & 0xFFFFFFFF

    def _geodetic(self) -> tuple[float, float, float]:
        v = self._v
        cache = self._geo_cache
        if cache is not None and cache[0] == v.steps:
            return cache[1]
        s = v.state
        geo = local_to_geodetic(v.origin, s.east_m, s.north_m, -s.down_m)
        self._geo_cache = (v.steps, geo)
        return geo

    def base_mode(self) -> int:
        v = self._v
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
        if v.mode is not FlightMode.POSCTL:
            base |= mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
        if v.mode is FlightMode.ORBIT:  # as PX4: a position-control sub mode, not an auto one
            base |= mavlink.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
        elif v.mode not in (FlightMode.POSCTL, FlightMode.OFFBOARD):
            base |= mavlink.MAV_MODE_FLAG_AUTO_ENABLED
        if v.armed:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        return base

    def heartbeat(self) -> Any:
        v = self._v
        if not v.armed:
            status = mavlink.MAV_STATE_STANDBY
        elif v.modes.failsafe_t is not None or v.geofence.action_mode is v.mode:
            status = mavlink.MAV_STATE_CRITICAL  # PX4 during a failsafe (offboard loss or the fence's action)
        else:
            status = mavlink.MAV_STATE_ACTIVE
        return self._mav.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, self.base_mode(),
                                          v.mode.custom_mode, status, 3)

    def sys_status(self) -> Any:
        v = self._v
        present, enabled, health = sensor_bits(v.sim_time_s, v.modes.armable())
        e = v.energy
        return self._mav.sys_status_encode(
            present, enabled, health, 100, int(e.voltage_v(v.battery_pct) * 1000),
            int(e.current_a(v.physics.drain_pct_s) * 100), int(round(v.battery_pct)), 0, 0, 0, 0, 0, 0)

    def extended_sys_state(self) -> Any:
        return self._mav.extended_sys_state_encode(mavlink.MAV_VTOL_STATE_UNDEFINED, int(self._v.landed_state))

    def local_position_ned(self) -> Any:
        s = self._v.state
        return self._mav.local_position_ned_encode(self.time_boot_ms, s.north_m, s.east_m, s.down_m,
                                                   s.vn_m_s, s.ve_m_s, s.vd_m_s)

    def global_position_int(self) -> Any:
        s = self._v.state
        lat, lon, alt = self._geodetic()
        hdg = int(round(math.degrees(s.yaw_rad) * 100.0)) % 36000
        return self._mav.global_position_int_encode(
            self.time_boot_ms, int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(alt * 1000.0)),
            int(round(-s.down_m * 1000.0)), _cm_s(s.vn_m_s), _cm_s(s.ve_m_s), _cm_s(s.vd_m_s), hdg)

    def attitude(self) -> Any:
        """Tilt into the acceleration, and the body yaw rate (heading rate x cos tilt), as PX4 reports them."""
        v = self._v
        s = v.state
        accel = None if v.plant is Plant.MULTICOPTER else v.physics.accel_ned  # the unicycle holds no thrust state
        roll, pitch, yawspeed = attitude(s, accel)
        return self._mav.attitude_encode(self.time_boot_ms, roll, pitch, s.yaw_rad, 0.0, 0.0, yawspeed)

    def gps_raw_int(self) -> Any:
        s = self._v.state
        lat, lon, alt = self._geodetic()
        speed = s.ground_speed_m_s
        cog = int(round(math.degrees(math.atan2(s.ve_m_s, s.vn_m_s)) * 100.0)) % 36000 if speed > 0.2 else 65535
        return self._mav.gps_raw_int_encode(
            int(self._v.sim_time_s * 1e6), mavlink.GPS_FIX_TYPE_3D_FIX, int(round(lat * 1e7)), int(round(lon * 1e7)),
            int(round(alt * 1000.0)), 70, 100, int(round(speed * 100.0)), cog, 12,
            int(round(alt * 1000.0)), 500, 800, 200, 0, 0)

    def home_position(self) -> Any:
        v = self._v
        n, e, d = v.home_ned
        lat, lon, alt = local_to_geodetic(v.origin, e, n, -d)
        return self._mav.home_position_encode(int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(alt * 1000.0)),
                                              n, e, d, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, int(v.sim_time_s * 1e6))

    def gps_global_origin(self) -> Any:
        o = self._v.origin
        return self._mav.gps_global_origin_encode(int(round(o.lat_deg * 1e7)), int(round(o.lon_deg * 1e7)),
                                                  int(round(o.alt_m * 1000.0)), int(self._v.sim_time_s * 1e6))

    def battery_status(self) -> Any:
        v = self._v
        e = v.energy
        drain = v.physics.drain_pct_s
        start = 100.0 if v.spec.battery_pct is None else v.spec.battery_pct
        frac = v.battery_pct / 100.0
        p = v.params
        charge = (mavlink.MAV_BATTERY_CHARGE_STATE_EMERGENCY if frac <= p["BAT_EMERGEN_THR"]
                  else mavlink.MAV_BATTERY_CHARGE_STATE_CRITICAL if frac <= p["BAT_CRIT_THR"]
                  else mavlink.MAV_BATTERY_CHARGE_STATE_LOW if frac <= p["BAT_LOW_THR"]
                  else mavlink.MAV_BATTERY_CHARGE_STATE_OK)
        voltages = [int(e.voltage_v(v.battery_pct) * 1000)] + [65535] * 9
        time_left = int(v.battery_pct / drain) if drain > 0 else 0
        return self._mav.battery_status_encode(
            0, mavlink.MAV_BATTERY_FUNCTION_ALL, mavlink.MAV_BATTERY_TYPE_LIPO, 32767, voltages,
            int(e.current_a(drain) * 100), int(e.consumed_mah(start, v.battery_pct)), -1,
            int(round(v.battery_pct)), time_left, charge)

    def mission_current(self) -> Any:
        v = self._v
        nav = v.nav
        n = len(v.missions.plan(MISSION))
        if n == 0:
            state = mavlink.MISSION_STATE_NO_MISSION
        elif nav.mission_done:
            state = mavlink.MISSION_STATE_COMPLETE
        elif v.mode is FlightMode.MISSION:
            state = mavlink.MISSION_STATE_ACTIVE
        elif nav.mission_started:
            state = mavlink.MISSION_STATE_PAUSED
        else:
            state = mavlink.MISSION_STATE_NOT_STARTED
        seq = min(nav.mission_index, max(0, n - 1))
        return self._mav.mission_current_encode(seq, n, state, 1 if v.mode is FlightMode.MISSION else 0)

    def adsb_vehicles(self) -> list[Any]:
        v = self._v
        out = []
        t = v.sim_time_s
        for k, o in enumerate(v.world.obstacles):
            if not o.is_moving:
                continue
            cx, cy = o.center_at(t)
            ve, vn = o.motion.velocity_at(t)
            lat, lon, alt = local_to_geodetic(v.origin, cx, cy, 0.0)
            speed = math.hypot(vn, ve)
            heading = int(round(math.degrees(math.atan2(ve, vn)) * 100.0)) % 36000
            out.append(self._mav.adsb_vehicle_encode(
                ADSB_ICAO_BASE + k, int(round(lat * 1e7)), int(round(lon * 1e7)),
                mavlink.ADSB_ALTITUDE_TYPE_GEOMETRIC, int(round(alt * 1000.0)), heading,
                int(round(speed * 100.0)) & 0xFFFF, 0, o.id[:8].encode("ascii", "replace"),
                mavlink.ADSB_EMITTER_TYPE_POINT_OBSTACLE, 0, ADSB_FLAGS, 0))
        return out

    def autopilot_version(self) -> Any:
        sid = self._v.system_id
        uid = (0x53494D << 40) | sid  # "SIM" + system id: unique per vehicle
        return self._mav.autopilot_version_encode(
            CAPABILITIES, PX4_FLIGHT_SW_VERSION, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, uid, [sid] + [0] * 17)

    def statustext(self, severity: int, text: str) -> Any:
        # The whole text: the vehicle's StatustextSplitter cuts it into 50-byte chunks on the way out.
        return self._mav.statustext_encode(severity, text.encode("ascii", "replace"))
