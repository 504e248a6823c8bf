"""One simulated vehicle: a PX4-like state machine over the kinematic plant. Sans-I/O.

``SimVehicle`` consumes decoded MAVLink messages and sim time, and emits MAVLink messages
(pymavlink objects, used as the codec's value types) tagged with where they go. It owns no
socket, no clock and no event loop, so every rule here is testable by calling methods:

    handle(msg, link, peer)   -> [Emit]   a message arrived on a link (replies go back there)
    step(dt_s)                -> [Emit]   advance physics and flight logic by one sim step
    telemetry(wall_t)         -> [Emit]   the streamed messages due on each link
    poll(wall_t)              -> [Emit]   wall-clock duties (mission transfer retries)

Frames: the plant and every MAVLink field are in PX4's local NED frame, whose origin is the
mission's geodetic origin for all vehicles (a shared EKF origin), so LOCAL_POSITION_NED of
either vehicle is directly comparable and maps to mission ENU through :mod:`uav_model.frames`.
"""

from __future__ import annotations

import logging
import math
import struct
from collections import Counter
from dataclasses import dataclass, replace
from enum import IntEnum
from typing import Any, Callable, Hashable, NamedTuple

from pymavlink.dialects.v20 import common as mavlink

from uav_model.frames import enu_heading_to_ned_yaw, geodetic_to_local, local_to_geodetic, wrap_pi
from uav_model.mission import Mission, VehicleSpec
from sim_bridge.energy import EnergyModel
from uav_model.plant import HOVER, KinematicState, PlantLimits, VelocityCommand, VelocityFrame, limits_for, step_for
from sim_bridge.mission_protocol import (
    MISSION, NOOP_COMMANDS, RELATIVE_ALT_FRAMES, MissionItem, MissionProtocol, ProtocolEvent,
)
from sim_bridge.px4 import PX4_FLIGHT_SW_VERSION, FlightMode, ParamDef, ParamType, decode_custom_mode, default_params
from sim_bridge.streams import API_PROFILE, StreamProfile, StreamScheduler
from sim_bridge.truth import CollisionChecker, CollisionEvent

log = logging.getLogger(__name__)

AUTOPILOT_COMPONENT_ID = mavlink.MAV_COMP_ID_AUTOPILOT1
FORCE_ARM_MAGIC = 21196  # COMPONENT_ARM_DISARM param2 that overrides the checks (MAVLink spec)

# SET_POSITION_TARGET_LOCAL_NED type_mask bits (set = ignore that field).
MASK_POSITION = (mavlink.POSITION_TARGET_TYPEMASK_X_IGNORE | mavlink.POSITION_TARGET_TYPEMASK_Y_IGNORE
                 | mavlink.POSITION_TARGET_TYPEMASK_Z_IGNORE)
MASK_VELOCITY = (mavlink.POSITION_TARGET_TYPEMASK_VX_IGNORE | mavlink.POSITION_TARGET_TYPEMASK_VY_IGNORE
                 | mavlink.POSITION_TARGET_TYPEMASK_VZ_IGNORE)
MASK_YAW = mavlink.POSITION_TARGET_TYPEMASK_YAW_IGNORE
MASK_YAW_RATE = mavlink.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
BODY_FRAMES = frozenset({mavlink.MAV_FRAME_BODY_NED, mavlink.MAV_FRAME_BODY_OFFSET_NED})
LOCAL_FRAMES = frozenset({mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_LOCAL_OFFSET_NED})

SENSORS_OK = (mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
              | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG | mavlink.MAV_SYS_STATUS_SENSOR_GPS)
PREARM_CHECK = mavlink.MAV_SYS_STATUS_PREARM_CHECK

CAPABILITIES = (mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
                | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
                | mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE
                | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_RALLY)

ADSB_ICAO_BASE = 0xAD0000  # ICAO address of obstacle k (index in mission.world.obstacles) = base + k
ADSB_FLAGS = (mavlink.ADSB_FLAGS_VALID_COORDS | mavlink.ADSB_FLAGS_VALID_ALTITUDE | mavlink.ADSB_FLAGS_VALID_HEADING
              | mavlink.ADSB_FLAGS_VALID_VELOCITY | mavlink.ADSB_FLAGS_VALID_CALLSIGN | mavlink.ADSB_FLAGS_SIMULATED)

KP_POSITION_1_S = 1.0  # position-hold / goto gain: 1 m error -> 1 m/s
KP_ALTITUDE_1_S = 1.0
IN_AIR_ALT_M = 0.3  # land detector: above this the vehicle flies
TOUCHDOWN_ALT_M = 0.02
MISSION_ALT_ACCEPT_M = 1.0  # PX4 NAV_MC_ALT_RAD is 0.8 m
LAND_POSITION_ACCEPT_M = 1.0
GRAVITY_M_S2 = 9.80665


class LandedState(IntEnum):
    UNDEFINED = mavlink.MAV_LANDED_STATE_UNDEFINED
    ON_GROUND = mavlink.MAV_LANDED_STATE_ON_GROUND
    IN_AIR = mavlink.MAV_LANDED_STATE_IN_AIR
    TAKEOFF = mavlink.MAV_LANDED_STATE_TAKEOFF
    LANDING = mavlink.MAV_LANDED_STATE_LANDING


class Emit(NamedTuple):
    """A message leaving the vehicle. ``link`` None: every link; ``peer`` None: every peer."""

    msg: Any
    link: str | None = None
    peer: Hashable | None = None


@dataclass(frozen=True, slots=True)
class Setpoint:
    """The last valid offboard setpoint (NED; body frames rotate by yaw only)."""

    body: bool
    use_position: bool
    x_m: float
    y_m: float
    z_m: float
    vx_m_s: float
    vy_m_s: float
    vz_m_s: float
    yaw_rad: float | None
    yaw_rate_rad_s: float | None
    received_t_s: float


@dataclass(frozen=True, slots=True)
class OffboardLoss:
    """Offboard setpoints stopped at ``last_setpoint_t_s``; the failsafe hit at ``failsafe_t_s``."""

    last_setpoint_t_s: float
    failsafe_t_s: float


class _Command(NamedTuple):
    command: int
    params: tuple[float, float, float, float, float, float, float]  # 5, 6 in degrees for global frames
    frame: int | None  # None: COMMAND_LONG
    src: tuple[int, int]


def _float_bits_to_int32(value: float) -> int:
    return struct.unpack("<i", struct.pack("<f", value))[0]


def _int32_to_float_bits(value: int) -> float:
    return struct.unpack("<f", struct.pack("<i", int(value)))[0]


def _clip(v: float, lo: float, hi: float) -> float:
    return lo if v < lo else hi if v > hi else v


class SimVehicle:
    """A PX4-like multicopter: modes, arming, offboard, missions, params, telemetry, truth."""

    def __init__(self, spec: VehicleSpec, mission: Mission, *, speed_headroom: float = 1.0,
                 energy: EnergyModel | None = None, component_id: int = AUTOPILOT_COMPONENT_ID):
        self.spec = spec
        self.name = spec.name
        self.system_id = spec.system_id
        self.component_id = component_id
        self._origin = mission.origin
        self._world = mission.world
        self._checker = CollisionChecker(mission.world)
        self._energy = energy or EnergyModel()
        self._mav = mavlink.MAVLink(None, self.system_id, component_id)  # message factory only
        self.missions = MissionProtocol(self.system_id, component_id, self._mav)
        self.counters: Counter[str] = Counter()
        self._wall_t = 0.0  # last wall time the I/O layer reported (mission transfer timing)

        defs = default_params(self.system_id, spec.speed_m_s * speed_headroom, spec.max_yaw_rate_rad_s,
                              spec.max_accel_m_s2, spec.cruise_alt_m)
        self._param_defs: dict[str, ParamDef] = {d.name: d for d in defs}
        self._param_order: tuple[str, ...] = tuple(d.name for d in defs)
        self._params: dict[str, float] = {d.name: float(d.default) for d in defs}
        self._max_alt_m = max(500.0, 2.0 * spec.cruise_alt_m)
        self._plant = mission.plant
        self._plant_step = step_for(mission.plant)
        self._limits = self._limits_from_params()

        home_x, home_y = spec.start_enu_m
        self.home_ned = (home_y, home_x, 0.0)
        self.sim_time_s = 0.0
        self._state = KinematicState(north_m=home_y, east_m=home_x, down_m=0.0,
                                     yaw_rad=enu_heading_to_ned_yaw(spec.initial_heading_rad))
        self._accel_ned = (0.0, 0.0)
        self.armed = False
        self.mode = FlightMode.HOLD
        self._in_air = False
        self._armed_t: float | None = None
        self._took_off_since_arm = False
        self._landed_t: float | None = None
        self.battery_pct = float(spec.battery_pct)
        self._drain_pct_s = 0.0
        self._battery_warned = 0  # 0 none, 1 low, 2 critical, 3 emergency

        self._hold_ned = self.home_ned
        self._takeoff_target_ned = self.home_ned
        self._land_ne = self.home_ned[:2]
        self._setpoint: Setpoint | None = None
        self.offboard_losses: list[OffboardLoss] = []
        self.collisions: list[CollisionEvent] = []
        self._inside: set[str] = set()

        self._mission_index = 0
        self._mission_phase: str | None = None
        self._mission_target = self.home_ned
        self._mission_hold_until: float | None = None
        self._mission_started = False
        self._mission_done = False
        self._mission_speed_m_s = self._params["MPC_XY_CRUISE"]
        self._rtl_phase = "climb"

        self._links: dict[str, StreamScheduler] = {}
        self._geo_cache: tuple[int, tuple[float, float, float]] | None = None
        self._steps = 0
        self._builders: dict[int, Callable[[], list[Any]]] = {
            mavlink.MAVLINK_MSG_ID_HEARTBEAT: lambda: [self._heartbeat()],
            mavlink.MAVLINK_MSG_ID_SYS_STATUS: lambda: [self._sys_status()],
            mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: lambda: [self._extended_sys_state()],
            mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: lambda: [self._local_position_ned()],
            mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: lambda: [self._global_position_int()],
            mavlink.MAVLINK_MSG_ID_ATTITUDE: lambda: [self._attitude()],
            mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: lambda: [self._gps_raw_int()],
            mavlink.MAVLINK_MSG_ID_HOME_POSITION: lambda: [self._home_position()],
            mavlink.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN: lambda: [self._gps_global_origin()],
            mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: lambda: [self._battery_status()],
            mavlink.MAVLINK_MSG_ID_MISSION_CURRENT: lambda: [self._mission_current()],
            mavlink.MAVLINK_MSG_ID_ADSB_VEHICLE: self._adsb_vehicles,
            mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION: lambda: [self._autopilot_version()],
        }
        self._handlers: dict[str, Callable[[Any, str, Hashable], list[Emit]]] = {
            "COMMAND_LONG": self._on_command_long,
            "COMMAND_INT": self._on_command_int,
            "SET_POSITION_TARGET_LOCAL_NED": self._on_set_position_target_local_ned,
            "SET_MODE": self._on_set_mode,
            "PARAM_SET": self._on_param_set,
            "PARAM_REQUEST_READ": self._on_param_request_read,
            "PARAM_REQUEST_LIST": self._on_param_request_list,
            "MISSION_SET_CURRENT": self._on_mission_set_current,
            "TIMESYNC": self._on_timesync,
        }
        self._commands: dict[int, Callable[[_Command, str, Hashable], tuple[int, list[Emit]]]] = {
            mavlink.MAV_CMD_REQUEST_MESSAGE: self._cmd_request_message,
            mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: self._cmd_request_autopilot_capabilities,
            mavlink.MAV_CMD_SET_MESSAGE_INTERVAL: self._cmd_set_message_interval,
            mavlink.MAV_CMD_GET_MESSAGE_INTERVAL: self._cmd_get_message_interval,
            mavlink.MAV_CMD_COMPONENT_ARM_DISARM: self._cmd_arm_disarm,
            mavlink.MAV_CMD_NAV_TAKEOFF: self._cmd_takeoff,
            mavlink.MAV_CMD_NAV_LAND: self._cmd_land,
            mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH: self._cmd_rtl,
            mavlink.MAV_CMD_DO_SET_MODE: self._cmd_set_mode,
            mavlink.MAV_CMD_MISSION_START: self._cmd_mission_start,
            mavlink.MAV_CMD_DO_SET_MISSION_CURRENT: self._cmd_set_mission_current,
            mavlink.MAV_CMD_DO_CHANGE_SPEED: self._cmd_change_speed,
            mavlink.MAV_CMD_DO_REPOSITION: self._cmd_reposition,
        }

    # ================================================================== public state ======
    @property
    def state(self) -> KinematicState:
        return self._state

    @property
    def limits(self) -> PlantLimits:
        return self._limits

    @property
    def in_air(self) -> bool:
        return self._in_air

    @property
    def landed_state(self) -> LandedState:
        if not self._in_air:
            return LandedState.ON_GROUND
        if self.armed and self.mode is FlightMode.TAKEOFF:
            return LandedState.TAKEOFF
        if self.armed and self._descending_to_land():
            return LandedState.LANDING
        return LandedState.IN_AIR

    @property
    def position_enu_m(self) -> tuple[float, float, float]:
        s = self._state
        return s.east_m, s.north_m, -s.down_m

    @property
    def collision_count(self) -> int:
        return len(self.collisions)

    @property
    def mission_index(self) -> int:
        return self._mission_index

    @property
    def mission_finished(self) -> bool:
        return self._mission_done

    @property
    def setpoint(self) -> Setpoint | None:
        return self._setpoint

    def param(self, name: str) -> float:
        return self._params[name]

    def add_link(self, link: str, profile: StreamProfile = API_PROFILE) -> None:
        """Register a link: its streams start at the profile's default rates."""
        self._links[link] = StreamScheduler(profile)

    def link_interval_s(self, link: str, msg_id: int) -> float | None:
        return self._links[link].interval_s(msg_id)

    # ================================================================== input =============
    def handle(self, msg: Any, link: str, peer: Hashable = None) -> list[Emit]:
        """React to one decoded message from ``link``/``peer``. Never raises."""
        try:
            return self._handle(msg, link, peer)
        except Exception:  # noqa: BLE001 - a bad message must never take the vehicle down
            self.counters["handler_error"] += 1
            log.exception("%s: error handling %s", self.name, getattr(msg, "get_type", lambda: "?")())
            return []

    def _handle(self, msg: Any, link: str, peer: Hashable) -> list[Emit]:
        name = msg.get_type()
        if name == "BAD_DATA":
            self.counters["bad_data"] += 1
            return []
        target = getattr(msg, "target_system", None)
        if target is not None and target not in (0, self.system_id):
            self.counters["wrong_target"] += 1
            return []
        comp = getattr(msg, "target_component", None)
        if comp is not None and comp not in (0, self.component_id):
            self.counters["other_component"] += 1
            return []
        handler = self._handlers.get(name)
        if handler is not None:
            return handler(msg, link, peer)
        if name.startswith("MISSION_"):
            replies, events = self.missions.handle(msg, link, peer, self._wall_t)
            out = [Emit(r.msg, r.link, r.peer) for r in replies]
            for ev in events:
                out += self._on_plan_event(ev)
            return out
        if name not in ("HEARTBEAT", "REQUEST_DATA_STREAM", "SYSTEM_TIME", "PING"):
            self.counters["unhandled"] += 1
        return []

    def poll(self, wall_t: float) -> list[Emit]:
        """Wall-clock duties; call often (every loop iteration)."""
        self._wall_t = wall_t
        return [Emit(r.msg, r.link, r.peer) for r in self.missions.poll(wall_t)]

    # ---------------------------------------------------------------- commands ------------
    def _on_command_long(self, msg: Any, link: str, peer: Hashable) -> list[Emit]:
        cmd = _Command(int(msg.command), (float(msg.param1), float(msg.param2), float(msg.param3), float(msg.param4),
                                          float(msg.param5), float(msg.param6), float(msg.param7)),
                       None, (msg.get_srcSystem(), msg.get_srcComponent()))
        return self._run_command(cmd, link, peer)

    def _on_command_int(self, msg: Any, link: str, peer: Hashable) -> list[Emit]:
        frame = int(msg.frame)
        scale = 1e-7 if frame in (mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_FRAME_GLOBAL_INT,
                                  mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT) else 1.0
        cmd = _Command(int(msg.command), (float(msg.param1), float(msg.param2), float(msg.param3), float(msg.param4),
                                          msg.x * scale, msg.y * scale, float(msg.z)),
                       frame, (msg.get_srcSystem(), msg.get_srcComponent()))
        return self._run_command(cmd, link, peer)

    def _run_command(self, cmd: _Command, link: str, peer: Hashable) -> list[Emit]:
        handler = self._commands.get(cmd.command)
        extra: list[Emit] = []
        if handler is None:
            result = mavlink.MAV_RESULT_UNSUPPORTED
            self.counters["command_unsupported"] += 1
        else:
            try:
                result, extra = handler(cmd, link, peer)
            except Exception:  # noqa: BLE001 - answer FAILED rather than stay silent
                log.exception("%s: command %d failed", self.name, cmd.command)
                self.counters["handler_error"] += 1
                result, extra = mavlink.MAV_RESULT_FAILED, []
            if result == mavlink.MAV_RESULT_DENIED:
                self.counters["command_denied"] += 1
        ack = self._mav.command_ack_encode(cmd.command, result, 0, 0, cmd.src[0], cmd.src[1])
        return [Emit(ack, link, peer)] + extra

    def _cmd_request_message(self, cmd: _Command, link: str, peer: Hashable) -> tuple[int, list[Emit]]:
        msg_id = cmd.params[0]
        if not math.isfinite(msg_id) or msg_id < 0 or msg_id != int(msg_id):
            return mavlink.MAV_RESULT_DENIED, []
        builder = self._builders.get(int(msg_id))
        if builder is None:
            return mavlink.MAV_RESULT_UNSUPPORTED, []
        return mavlink.MAV_RESULT_ACCEPTED, [Emit(m, link, peer) for m in builder()]

    def _cmd_request_autopilot_capabilities(self, cmd: _Command, link: str, peer: Hashable) -> tuple[int, list[Emit]]:
        return mavlink.MAV_RESULT_ACCEPTED, [Emit(self._autopilot_version(), link, peer)]

    def _cmd_set_message_interval(self, cmd: _Command, link: str, peer: Hashable) -> tuple[int, list[Emit]]:
        msg_id, interval_us = cmd.params[0], cmd.params[1]
        if not (math.isfinite(msg_id) and math.isfinite(interval_us)) or msg_id < 0 or interval_us < -1:
            return mavlink.MAV_RESULT_DENIED, []
        if int(msg_id) not in self._builders or int(msg_id) == mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            return mavlink.MAV_RESULT_UNSUPPORTED, []
        sched = self._links.get(link)
        if sched is None:
            return mavlink.MAV_RESULT_FAILED, []
        if interval_us == -1:
            sched.set_interval(int(msg_id), None)
        elif interval_us == 0:
            sched.reset_default(int(msg_id))
        else:
            sched.set_interval(int(msg_id), max(interval_us, 1000.0) / 1e6)
        return mavlink.MAV_RESULT_ACCEPTED, []

    def _cmd_get_message_interval(self, cmd: _Command, link: str, peer: Hashable) -> tuple[int, list[Emit]]:
        msg_id = cmd.params[0]
        if not math.isfinite(msg_id) or msg_id < 0 or msg_id > 2**24:
            return mavlink.MAV_RESULT_DENIED, []
        sched = self._links.get(link)
        if int(msg_id) not in self._builders or sched is None:
            interval_us = 0  # "not available"
        else:
            interval = sched.interval_s(int(msg_id))
            interval_us = -1 if interval is None else int(round(interval * 1e6))
        return mavlink.MAV_RESULT_ACCEPTED, [Emit(self._mav.message_interval_encode(int(msg_id), interval_us), link, peer)]

    def _cmd_arm_disarm(self, cmd: _Command, link: str, peer: Hashable) -> tuple[int, list[Emit]]:
        arm, force = cmd.params[0], cmd.params[1]
        forced = force == FORCE_ARM_MAGIC
        if arm == 1.0:
            return self._arm(forced)
        if arm == 0.0:
            return self._disarm(forced, "external command")
        return mavlink.MAV_RESULT_DENIED, []

    def _cmd_takeoff(self, cmd: _Command, link: str, peer: Hashable) -> tuple[int, list[Emit]]:
        yaw_deg, alt = cmd.params[3], cmd.params[6]
        if math.isfinite(alt):
            # COMMAND_LONG altitude is AMSL (MAV_FRAME_GLOBAL); COMMAND_INT says its frame.
            rel = alt if cmd.frame in RELATIVE_ALT_FRAMES else alt - self._origin.alt_m
        else:
            rel = self._params["MIS_TAKEOFF_ALT"]
        if not (0.5 <= rel <= self._max_alt_m) or math.isinf(yaw_deg):  # NaN yaw: keep the heading
            return mavlink.MAV_RESULT_DENIED, []
        s = self._state
        return self._enter_mode(FlightMode.TAKEOFF, takeoff_ned=(s.north_m, s.east_m, -rel)), self._mode_emits()

    def _cmd_land(self, cmd: _Command, link: str, peer: Hashable) -> tuple[int, list[Emit]]:
        lat, lon = cmd.params[4], cmd.params[5]
        land_ne = None
        if math.isfinite(lat) and math.isfinite(lon) and not (lat == 0.0 and lon == 0.0):
            if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
                return mavlink.MAV_RESULT_DENIED, []
            x, y, _ = geodetic_to_local(self._origin, lat, lon)
            land_ne = (y, x)
        return self._enter_mode(FlightMode.LAND, land_ne=land_ne), self._mode_emits()

    def _cmd_rtl(self, cmd: _Command, link: str, peer: Hashable) -> tuple[int, list[Emit]]:
        return self._enter_mode(FlightMode.RTL), self._mode_emits()

    def _cmd_set_mode(self, cmd: _Command, link: str, peer: Hashable) -> tuple[int, list[Emit]]:
        base, main, sub = cmd.params[0], cmd.params[1], cmd.params[2]
        if not all(math.isfinite(v) for v in (base, main)):
            return mavlink.MAV_RESULT_DENIED, []
        if not int(base) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return mavlink.MAV_RESULT_DENIED, []  # PX4 modes are custom modes
        sub_i = int(sub) if math.isfinite(sub) else 0
        mode = FlightMode.from_px4(int(main), sub_i)
        if mode is None:
            return mavlink.MAV_RESULT_DENIED, []
        return self._enter_mode(mode), self._mode_emits()

    def _on_set_mode(self, msg: Any, link: str, peer: Hashable) -> list[Emit]:
        """Legacy SET_MODE message: acked as DO_SET_MODE, as PX4 does."""
        main, sub = decode_custom_mode(int(msg.custom_mode))
        mode = FlightMode.from_px4(main, sub) if msg.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED else None
        result = mavlink.MAV_RESULT_DENIED if mode is None else self._enter_mode(mode)
        ack = self._mav.command_ack_encode(mavlink.MAV_CMD_DO_SET_MODE, result, 0, 0,
                                           msg.get_srcSystem(), msg.get_srcComponent())
        return [Emit(ack, link, peer)] + self._mode_emits()

    def _cmd_mission_start(self, cmd: _Command, link: str, peer: Hashable) -> tuple[int, list[Emit]]:
        first = cmd.params[0]
        plan = self.missions.plan(MISSION)
        if math.isfinite(first) and first > 0:
            if first != int(first) or first >= len(plan):
                return mavlink.MAV_RESULT_DENIED, []
            self._set_mission_index(int(first))
        return self._enter_mode(FlightMode.MISSION), self._mode_emits()

    def _cmd_set_mission_current(self, cmd: _Command, link: str, peer: Hashable) -> tuple[int, list[Emit]]:
        seq = cmd.params[0]
        plan = self.missions.plan(MISSION)
        if not math.isfinite(seq) or seq != int(seq) or not 0 <= seq < max(1, len(plan)):
            return mavlink.MAV_RESULT_DENIED, []
        self._set_mission_index(int(seq))
        return mavlink.MAV_RESULT_ACCEPTED, [Emit(self._mission_current())]

    def _on_mission_set_current(self, msg: Any, link: str, peer: Hashable) -> list[Emit]:
        plan = self.missions.plan(MISSION)
        if 0 <= msg.seq < len(plan):
            self._set_mission_index(int(msg.seq))
        else:
            self.counters["bad_mission_set_current"] += 1
            return [Emit(self._statustext(mavlink.MAV_SEVERITY_WARNING, f"Mission item {msg.seq} does not exist"),
                         link, peer), Emit(self._mission_current(), link, peer)]
        return [Emit(self._mission_current())]

    def _cmd_change_speed(self, cmd: _Command, link: str, peer: Hashable) -> tuple[int, list[Emit]]:
        speed = cmd.params[1]
        if not math.isfinite(speed) or speed > 1000.0:
            return mavlink.MAV_RESULT_DENIED, []
        if speed > 0:
            self._mission_speed_m_s = min(speed, self._limits.max_speed_m_s)
        return mavlink.MAV_RESULT_ACCEPTED, []

    def _cmd_reposition(self, cmd: _Command, link: str, peer: Hashable) -> tuple[int, list[Emit]]:
        """Go to a point and hold there (PX4: DO_REPOSITION switches to Hold at the target)."""
        lat, lon, alt = cmd.params[4], cmd.params[5], cmd.params[6]
        if not (self.armed and self._in_air):
            return mavlink.MAV_RESULT_DENIED, []
        if not (math.isfinite(lat) and math.isfinite(lon) and -90 <= lat <= 90 and -180 <= lon <= 180):
            return mavlink.MAV_RESULT_DENIED, []
        x, y, _ = geodetic_to_local(self._origin, lat, lon)
        if math.isfinite(alt):
            rel = alt if cmd.frame in RELATIVE_ALT_FRAMES else alt - self._origin.alt_m
        else:
            rel = -self._state.down_m
        if not 0.0 <= rel <= self._max_alt_m:
            return mavlink.MAV_RESULT_DENIED, []
        result = self._enter_mode(FlightMode.HOLD)
        self._hold_ned = (y, x, -rel)
        return result, self._mode_emits()

    # ---------------------------------------------------------------- arming -------------
    def _armable(self) -> bool:
        return self.battery_pct > 100.0 * self._params["BAT_CRIT_THR"]

    def _arm(self, forced: bool) -> tuple[int, list[Emit]]:
        if self.armed:
            return mavlink.MAV_RESULT_ACCEPTED, []
        if self._in_air:
            return mavlink.MAV_RESULT_DENIED, []  # a falling, disarmed vehicle does not re-arm
        if not forced:
            if self.mode in (FlightMode.LAND, FlightMode.RTL):
                return mavlink.MAV_RESULT_DENIED, [Emit(self._statustext(
                    mavlink.MAV_SEVERITY_CRITICAL, f"Arming denied: not in {self.mode.name} mode"))]
            if self.mode is FlightMode.OFFBOARD and not self._setpoints_fresh():
                return mavlink.MAV_RESULT_DENIED, [Emit(self._statustext(
                    mavlink.MAV_SEVERITY_CRITICAL, "Arming denied: no offboard signal"))]
            if not self._armable():
                return mavlink.MAV_RESULT_DENIED, [Emit(self._statustext(
                    mavlink.MAV_SEVERITY_CRITICAL, "Arming denied: battery too low"))]
        self.armed = True
        self._armed_t = self.sim_time_s
        self._took_off_since_arm = False
        self._landed_t = None
        if self.mode is FlightMode.MISSION:
            self._mission_enter()
        return mavlink.MAV_RESULT_ACCEPTED, [Emit(self._statustext(mavlink.MAV_SEVERITY_INFO, "Armed by external command")),
                                             Emit(self._heartbeat())]

    def _disarm(self, forced: bool, reason: str) -> tuple[int, list[Emit]]:
        if not self.armed:
            return mavlink.MAV_RESULT_ACCEPTED, []
        if self._in_air and not forced:
            return mavlink.MAV_RESULT_DENIED, [Emit(self._statustext(
                mavlink.MAV_SEVERITY_CRITICAL, "Disarming denied: not landed"))]
        self.armed = False
        self._armed_t = None
        return mavlink.MAV_RESULT_ACCEPTED, [Emit(self._statustext(mavlink.MAV_SEVERITY_INFO, f"Disarmed by {reason}")),
                                             Emit(self._heartbeat())]

    # ---------------------------------------------------------------- modes --------------
    def _setpoints_fresh(self) -> bool:
        sp = self._setpoint
        return sp is not None and self.sim_time_s - sp.received_t_s <= self._params["COM_OF_LOSS_T"]

    def _braking_point(self) -> tuple[float, float, float]:
        s = self._state
        speed = s.ground_speed_m_s
        if speed < 1e-3:
            return s.north_m, s.east_m, s.down_m
        k = speed / (2.0 * self._limits.max_accel_m_s2)  # v^2 / 2a along v, divided by v
        return s.north_m + s.vn_m_s * k, s.east_m + s.ve_m_s * k, s.down_m

    def _enter_mode(self, mode: FlightMode, *, takeoff_ned: tuple[float, float, float] | None = None,
                    land_ne: tuple[float, float] | None = None) -> int:
        """Switch flight mode if PX4 would; returns the MAV_RESULT."""
        s = self._state
        if mode is FlightMode.OFFBOARD and not self._setpoints_fresh():
            return mavlink.MAV_RESULT_DENIED
        if mode is FlightMode.MISSION and not self.missions.plan(MISSION):
            return mavlink.MAV_RESULT_DENIED
        if mode is FlightMode.RTL and not self._in_air:
            return mavlink.MAV_RESULT_DENIED
        if mode is self.mode and mode not in (FlightMode.TAKEOFF, FlightMode.LAND):
            return mavlink.MAV_RESULT_ACCEPTED
        if mode in (FlightMode.HOLD, FlightMode.POSCTL):
            self._hold_ned = self._braking_point()
        elif mode is FlightMode.TAKEOFF:
            self._takeoff_target_ned = takeoff_ned or (s.north_m, s.east_m, -self._params["MIS_TAKEOFF_ALT"])
        elif mode is FlightMode.LAND:
            self._land_ne = land_ne or self._braking_point()[:2]
        elif mode is FlightMode.RTL:
            self._rtl_phase = "climb"
            self._hold_ned = self._braking_point()
        self.mode = mode
        if mode is FlightMode.MISSION:
            self._mission_enter()
        return mavlink.MAV_RESULT_ACCEPTED

    def _mode_emits(self) -> list[Emit]:
        """A heartbeat right after a mode change, so every client sees it within one heartbeat."""
        return [Emit(self._heartbeat())]

    def _failsafe_hold(self, text: str) -> list[Emit]:
        self._enter_mode(FlightMode.HOLD)
        return [Emit(self._statustext(mavlink.MAV_SEVERITY_WARNING, text)), Emit(self._heartbeat())]

    # ---------------------------------------------------------------- offboard -----------
    def _on_set_position_target_local_ned(self, msg: Any, link: str, peer: Hashable) -> list[Emit]:
        mask, frame = int(msg.type_mask), int(msg.coordinate_frame)
        use_pos = (mask & MASK_POSITION) == 0
        use_vel = (mask & MASK_VELOCITY) == 0
        partial = (0 < mask & MASK_POSITION < MASK_POSITION) or (0 < mask & MASK_VELOCITY < MASK_VELOCITY)
        body = frame in BODY_FRAMES
        valid_frame = body or frame in LOCAL_FRAMES
        values = []
        if use_pos:
            values += [msg.x, msg.y, msg.z]
        if use_vel:
            values += [msg.vx, msg.vy, msg.vz]
        yaw = None if mask & MASK_YAW or not math.isfinite(msg.yaw) else float(msg.yaw)
        yaw_rate = None if mask & MASK_YAW_RATE or not math.isfinite(msg.yaw_rate) else float(msg.yaw_rate)
        if (partial or not (use_pos or use_vel) or not valid_frame or (use_pos and body)
                or not all(math.isfinite(v) for v in values)):
            self.counters["invalid_setpoint"] += 1
            return []
        x, y, z = (float(msg.x), float(msg.y), float(msg.z)) if use_pos else (0.0, 0.0, 0.0)
        if use_pos and frame == mavlink.MAV_FRAME_LOCAL_OFFSET_NED:
            x, y, z = x + self._state.north_m, y + self._state.east_m, z + self._state.down_m
        self._setpoint = Setpoint(
            body=body, use_position=use_pos and not use_vel, x_m=x, y_m=y, z_m=z,
            vx_m_s=float(msg.vx) if use_vel else 0.0, vy_m_s=float(msg.vy) if use_vel else 0.0,
            vz_m_s=float(msg.vz) if use_vel else 0.0, yaw_rad=yaw, yaw_rate_rad_s=yaw_rate,
            received_t_s=self.sim_time_s)
        self.counters["setpoints"] += 1
        return []

    # ---------------------------------------------------------------- params -------------
    def _param_value_msg(self, name: str) -> Any:
        d = self._param_defs[name]
        value = self._params[name]
        wire = _int32_to_float_bits(int(value)) if d.type is ParamType.INT32 else value  # PX4 is bytewise
        return self._mav.param_value_encode(name.encode("ascii"), wire, int(d.type), len(self._param_order),
                                            self._param_order.index(name))

    def _on_param_set(self, msg: Any, link: str, peer: Hashable) -> list[Emit]:
        name = str(msg.param_id).rstrip("\x00")
        d = self._param_defs.get(name)
        if d is None:
            self.counters["param_unknown"] += 1
            return []
        raw = float(msg.param_value)
        value = float(_float_bits_to_int32(raw)) if d.type is ParamType.INT32 else raw
        if not d.accepts(value):
            self.counters["param_rejected"] += 1
            return [Emit(self._statustext(mavlink.MAV_SEVERITY_WARNING, f"param {name}: {value!r} rejected"), link, peer),
                    Emit(self._param_value_msg(name), link, peer)]
        self._params[name] = value
        self._limits = self._limits_from_params()
        if name == "MPC_XY_CRUISE":
            self._mission_speed_m_s = value
        return [Emit(self._param_value_msg(name))]  # PX4 broadcasts a changed value

    def _on_param_request_read(self, msg: Any, link: str, peer: Hashable) -> list[Emit]:
        idx = int(msg.param_index)
        if idx >= 0:
            if idx >= len(self._param_order):
                self.counters["param_unknown"] += 1
                return []
            name = self._param_order[idx]
        else:
            name = str(msg.param_id).rstrip("\x00")
            if name not in self._param_defs:
                self.counters["param_unknown"] += 1
                return []
        return [Emit(self._param_value_msg(name), link, peer)]

    def _on_param_request_list(self, msg: Any, link: str, peer: Hashable) -> list[Emit]:
        return [Emit(self._param_value_msg(n), link, peer) for n in self._param_order]

    def _limits_from_params(self) -> PlantLimits:
        p = self._params
        return limits_for(self._plant, speed_m_s=p["MPC_XY_VEL_MAX"], max_yaw_rate_rad_s=math.radians(p["MPC_YAWRAUTO_MAX"]),
                          max_accel_m_s2=p["MPC_ACC_HOR"], max_climb_m_s=max(p["MPC_Z_VEL_MAX_UP"], p["MPC_Z_VEL_MAX_DN"]),
                          max_alt_m=self._max_alt_m, params=p)

    def _on_timesync(self, msg: Any, link: str, peer: Hashable) -> list[Emit]:
        if msg.tc1 != 0:
            return []
        return [Emit(self._mav.timesync_encode(int(self.sim_time_s * 1e9), msg.ts1), link, peer)]

    # ================================================================== physics ===========
    def step(self, dt_s: float) -> list[Emit]:
        """Advance one physics step of ``dt_s`` sim seconds. Never raises."""
        try:
            return self._step(dt_s)
        except Exception:  # noqa: BLE001 - keep flying (time still advances) and say so
            self.counters["step_error"] += 1
            if self.counters["step_error"] <= 5:
                log.exception("%s: error in physics step at t=%.2f", self.name, self.sim_time_s)
            self.sim_time_s += dt_s
            return []

    def _step(self, dt_s: float) -> list[Emit]:
        out: list[Emit] = []
        t0 = self.sim_time_s
        t1 = t0 + dt_s
        old = self._state
        command = self._control(dt_s)
        if command is None:  # on the ground, not climbing: nothing moves
            new = KinematicState(old.north_m, old.east_m, old.down_m, yaw_rad=old.yaw_rad)
        else:
            new = self._plant_step(old, command, self._limits, dt_s)
        self._accel_ned = ((new.vn_m_s - old.vn_m_s) / dt_s, (new.ve_m_s - old.ve_m_s) / dt_s)
        self._state = new
        self.sim_time_s = t1
        self._steps += 1

        out += self._land_detector(t1)
        if self._in_air or -old.down_m > TOUCHDOWN_ALT_M:
            out += self._check_collisions(old, new, t0, t1)
        out += self._update_battery(dt_s)
        out += self._flight_logic(t1)
        return out

    def _land_detector(self, t: float) -> list[Emit]:
        s = self._state
        alt = -s.down_m
        if not self._in_air and alt > IN_AIR_ALT_M:
            self._in_air = True
            self._landed_t = None
            if self.armed:
                self._took_off_since_arm = True
        elif self._in_air and alt <= TOUCHDOWN_ALT_M and s.vd_m_s >= -0.05:
            self._in_air = False
            self._landed_t = t
            self._state = replace(s, down_m=0.0, vn_m_s=0.0, ve_m_s=0.0, vd_m_s=0.0, yawspeed_rad_s=0.0)
            return [Emit(self._statustext(mavlink.MAV_SEVERITY_INFO, "Landing detected"))]
        return []

    def _check_collisions(self, old: KinematicState, new: KinematicState, t0: float, t1: float) -> list[Emit]:
        hits = self._checker.hits(old.east_m, old.north_m, new.east_m, new.north_m, t0, t1)
        out: list[Emit] = []
        for oid in hits:
            if oid not in self._inside:
                ev = CollisionEvent(t1, oid, new.east_m, new.north_m)
                self.collisions.append(ev)
                log.warning("%s: COLLISION with %s at t=%.2f s (%.1f, %.1f)", self.name, oid, t1, ev.x_m, ev.y_m)
                out.append(Emit(self._statustext(mavlink.MAV_SEVERITY_CRITICAL,
                                                 f"COLLISION {self.name} with {oid} t={t1:.1f}s")))
        self._inside = set(hits)
        return out

    def _update_battery(self, dt_s: float) -> list[Emit]:
        s = self._state
        self._drain_pct_s = self._energy.drain_pct_s(self.armed, self._in_air, s.ground_speed_m_s, -s.vd_m_s)
        self.battery_pct = max(0.0, self.battery_pct - self._drain_pct_s * dt_s)
        frac = self.battery_pct / 100.0
        level = (3 if frac <= self._params["BAT_EMERGEN_THR"] else 2 if frac <= self._params["BAT_CRIT_THR"]
                 else 1 if frac <= self._params["BAT_LOW_THR"] else 0)
        if level > self._battery_warned:
            self._battery_warned = level
            text, sev = {1: ("Low battery level", mavlink.MAV_SEVERITY_WARNING),
                         2: ("Critical battery level", mavlink.MAV_SEVERITY_CRITICAL),
                         3: ("Emergency battery level", mavlink.MAV_SEVERITY_EMERGENCY)}[level]
            return [Emit(self._statustext(sev, f"{text}: {self.battery_pct:.0f}%"))]
        return []

    # ---------------------------------------------------------------- controllers --------
    def _yawspeed_toward(self, yaw_target: float, dt_s: float) -> float:
        """Auto-mode yaw: P on the angle (dead-beat on the unicycle), within MPC_YAWRAUTO_MAX."""
        err = wrap_pi(yaw_target - self._state.yaw_rad)
        rate = math.radians(self._params["MPC_YAWRAUTO_MAX"])
        return _clip(err * min(1.0 / dt_s, self._limits.yaw_p_1_s), -rate, rate)

    def _goto(self, target: tuple[float, float, float], speed_m_s: float, dt_s: float, *, stop: bool = True,
              yaw_rad: float | None = None, face_travel: bool = False, climb_m_s: float | None = None) -> VelocityCommand:
        """Velocity toward a NED point: cruise, brake to stop on it, altitude by P control."""
        s = self._state
        dn, de = target[0] - s.north_m, target[1] - s.east_m
        dist = math.hypot(dn, de)
        speed = min(speed_m_s, self._limits.max_speed_m_s)
        if stop:
            speed = min(speed, math.sqrt(1.6 * self._limits.max_accel_m_s2 * dist), KP_POSITION_1_S * dist)
        vn, ve = (dn / dist * speed, de / dist * speed) if dist > 1e-6 else (0.0, 0.0)
        up = self._params["MPC_Z_VEL_MAX_UP"] if climb_m_s is None else climb_m_s
        vd = _clip(KP_ALTITUDE_1_S * (target[2] - s.down_m), -up, self._params["MPC_Z_VEL_MAX_DN"])
        if yaw_rad is None and face_travel and dist > 2.0:
            yaw_rad = math.atan2(de, dn)
        yawspeed = 0.0 if yaw_rad is None else self._yawspeed_toward(yaw_rad, dt_s)
        return VelocityCommand(VelocityFrame.LOCAL_NED, vn, ve, vd, yawspeed)

    def _land_command(self, north_m: float, east_m: float, dt_s: float) -> VelocityCommand:
        p = self._params
        alt = -self._state.down_m
        fast, slow = p["MPC_Z_VEL_MAX_DN"], p["MPC_LAND_SPEED"]
        hi, lo = p["MPC_LAND_ALT1"], p["MPC_LAND_ALT2"]
        if alt >= hi:
            vd = fast
        elif alt > lo and hi > lo:
            vd = slow + (fast - slow) * (alt - lo) / (hi - lo)
        else:
            vd = slow
        cmd = self._goto((north_m, east_m, self._state.down_m), self._limits.max_speed_m_s, dt_s)
        return replace(cmd, z_m_s=vd)

    def _descending_to_land(self) -> bool:
        return (self.mode is FlightMode.LAND or (self.mode is FlightMode.RTL and self._rtl_phase == "land")
                or (self.mode is FlightMode.MISSION and self._mission_phase == "land"))

    def _control(self, dt_s: float) -> VelocityCommand | None:
        """The velocity command of the active mode, or None for "stay put on the ground"."""
        s = self._state
        if not self.armed:
            if self._in_air:  # disarmed in the air (forced): motors off, it drops
                return VelocityCommand(VelocityFrame.LOCAL_NED, 0.0, 0.0, self._limits.max_climb_m_s, 0.0)
            return None
        mode = self.mode
        if mode is FlightMode.OFFBOARD:
            cmd = self._offboard_command(dt_s)
        elif mode in (FlightMode.HOLD, FlightMode.POSCTL):
            cmd = self._goto(self._hold_ned, self._limits.max_speed_m_s, dt_s) if self._in_air else None
        elif mode is FlightMode.TAKEOFF:
            cmd = self._goto(self._takeoff_target_ned, 0.0 if not self._in_air else self._limits.max_speed_m_s, dt_s,
                             climb_m_s=self._params["MPC_TKO_SPEED"])
        elif mode is FlightMode.LAND:
            cmd = self._land_command(*self._land_ne, dt_s) if self._in_air else None
        elif mode is FlightMode.MISSION:
            cmd = self._mission_command(dt_s)
        elif mode is FlightMode.RTL:
            cmd = self._rtl_command(dt_s)
        else:  # pragma: no cover - every FlightMode is handled above
            cmd = HOVER
        if cmd is None:
            return None
        if not self._in_air and s.down_m >= -TOUCHDOWN_ALT_M and cmd.z_m_s >= 0.0:
            return None  # on the ground and not climbing: no sliding about
        return cmd

    def _offboard_command(self, dt_s: float) -> VelocityCommand | None:
        sp = self._setpoint
        if sp is None:
            return HOVER
        if sp.yaw_rate_rad_s is not None:
            yawspeed = sp.yaw_rate_rad_s
        elif sp.yaw_rad is not None:
            yawspeed = self._yawspeed_toward(sp.yaw_rad, dt_s)
        else:
            yawspeed = 0.0
        if sp.use_position:
            cmd = self._goto((sp.x_m, sp.y_m, sp.z_m), self._limits.max_speed_m_s, dt_s, yaw_rad=sp.yaw_rad)
            return replace(cmd, yawspeed_rad_s=yawspeed)
        frame = VelocityFrame.BODY_NED if sp.body else VelocityFrame.LOCAL_NED
        return VelocityCommand(frame, sp.vx_m_s, sp.vy_m_s, sp.vz_m_s, yawspeed)

    def _rtl_command(self, dt_s: float) -> VelocityCommand | None:
        if not self._in_air:
            return None
        rtl_alt = max(self._params["RTL_RETURN_ALT"], 0.5)
        home_n, home_e, _ = self.home_ned
        cruise = self._params["MPC_XY_CRUISE"]
        if self._rtl_phase == "climb":
            return self._goto((self._hold_ned[0], self._hold_ned[1], min(-rtl_alt, self._state.down_m)), cruise, dt_s)
        if self._rtl_phase == "return":
            return self._goto((home_n, home_e, min(-rtl_alt, self._hold_ned[2])), cruise, dt_s, face_travel=True)
        return self._land_command(home_n, home_e, dt_s)

    # ---------------------------------------------------------------- flight logic -------
    def _flight_logic(self, t: float) -> list[Emit]:
        out: list[Emit] = []
        p = self._params
        s = self._state
        if self.mode is FlightMode.OFFBOARD:
            sp = self._setpoint
            if sp is None or t - sp.received_t_s > p["COM_OF_LOSS_T"]:
                self.offboard_losses.append(OffboardLoss(sp.received_t_s if sp else -1.0, t))
                out += self._failsafe_hold("Offboard control lost: switching to Hold")
        elif self.mode is FlightMode.TAKEOFF and self.armed and self._in_air:
            if -s.down_m >= -self._takeoff_target_ned[2] - 0.2:
                self._enter_mode(FlightMode.HOLD)
                self._hold_ned = (self._takeoff_target_ned[0], self._takeoff_target_ned[1], self._takeoff_target_ned[2])
                out += [Emit(self._statustext(mavlink.MAV_SEVERITY_INFO, "Takeoff complete")), Emit(self._heartbeat())]
        elif self.mode is FlightMode.MISSION and self.armed:
            out += self._mission_update(t)
        elif self.mode is FlightMode.RTL and self.armed and self._in_air:
            rtl_alt = max(p["RTL_RETURN_ALT"], 0.5)
            if self._rtl_phase == "climb" and -s.down_m >= rtl_alt - MISSION_ALT_ACCEPT_M:
                self._rtl_phase = "return"
                self._hold_ned = (s.north_m, s.east_m, s.down_m)
            elif self._rtl_phase == "return":
                if math.hypot(self.home_ned[0] - s.north_m, self.home_ned[1] - s.east_m) <= LAND_POSITION_ACCEPT_M:
                    self._rtl_phase = "land"
        if self.armed and not self._in_air:
            if (self._landed_t is not None and p["COM_DISARM_LAND"] >= 0
                    and t - self._landed_t >= p["COM_DISARM_LAND"]):
                out += self._disarm(True, "auto disarm after landing")[1]
            elif (not self._took_off_since_arm and self._armed_t is not None and p["COM_DISARM_PRFLT"] >= 0
                  and t - self._armed_t >= p["COM_DISARM_PRFLT"]):
                out += self._disarm(True, "auto disarm: no takeoff")[1]
        return out

    # ---------------------------------------------------------------- mission flying -----
    def _on_plan_event(self, ev: ProtocolEvent) -> list[Emit]:
        if ev.mission_type != MISSION:
            return []
        self._mission_index = 0
        self._mission_phase = None
        self._mission_started = False
        self._mission_done = False
        self.missions.current_seq = 0
        out = [Emit(self._mission_current())]
        if self.mode is FlightMode.MISSION:
            if ev.kind == "cleared":
                out += self._failsafe_hold("Mission cleared: switching to Hold")
            else:
                self._mission_enter()
        return out

    def _set_mission_index(self, seq: int) -> None:
        self._mission_index = seq
        self._mission_phase = None
        self._mission_hold_until = None
        self._mission_done = False
        self.missions.current_seq = seq

    def _mission_enter(self) -> None:
        plan = self.missions.plan(MISSION)
        if self._mission_done or self._mission_index >= len(plan):
            self._set_mission_index(0)
        self._mission_phase = None
        self._mission_started = True
        self._mission_speed_m_s = self._params["MPC_XY_CRUISE"]

    def _item_target_ned(self, item: MissionItem) -> tuple[float, float, float]:
        s = self._state
        if item.command in (mavlink.MAV_CMD_NAV_TAKEOFF,) or (item.command == mavlink.MAV_CMD_NAV_LAND and item.x == 0 and item.y == 0):
            north, east = s.north_m, s.east_m
        else:
            x, y, _ = geodetic_to_local(self._origin, item.lat_deg, item.lon_deg)
            north, east = y, x
        rel = item.z if item.frame in RELATIVE_ALT_FRAMES else item.z - self._origin.alt_m
        if item.command == mavlink.MAV_CMD_NAV_LAND:
            return north, east, s.down_m
        return north, east, -_clip(rel, 0.0, self._max_alt_m)

    def _mission_command(self, dt_s: float) -> VelocityCommand | None:
        phase = self._mission_phase
        if phase is None or self._mission_done:
            return self._goto(self._hold_ned, self._limits.max_speed_m_s, dt_s) if self._in_air else None
        target = self._mission_target
        if phase == "takeoff":
            return self._goto(target, 0.0, dt_s, climb_m_s=self._params["MPC_TKO_SPEED"])
        if phase == "land":
            return self._land_command(target[0], target[1], dt_s)
        stop = phase == "hold" or self._mission_stop_at_target()
        return self._goto(target, self._mission_speed_m_s, dt_s, stop=stop, face_travel=True)

    def _mission_stop_at_target(self) -> bool:
        plan = self.missions.plan(MISSION)
        item = plan[self._mission_index]
        if item.command != mavlink.MAV_CMD_NAV_WAYPOINT or item.param1 > 0:
            return True
        return not any(it.has_position for it in plan[self._mission_index + 1:])

    def _mission_update(self, t: float) -> list[Emit]:
        """Advance through the plan; done-at-once items chain within one step."""
        plan = self.missions.plan(MISSION)
        out: list[Emit] = []
        s = self._state
        for _ in range(len(plan) + 1):
            if self._mission_done:
                return out
            if self._mission_index >= len(plan):
                return out + self._mission_finish("Mission finished")
            item = plan[self._mission_index]
            cmd = item.command
            if cmd == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
                out.append(Emit(self._mav.mission_item_reached_encode(item.seq)))
                self._mission_done = True
                self._enter_mode(FlightMode.RTL)
                return out + [Emit(self._heartbeat())]
            if cmd in NOOP_COMMANDS:
                if cmd == mavlink.MAV_CMD_DO_CHANGE_SPEED and item.param2 > 0:
                    self._mission_speed_m_s = min(item.param2, self._limits.max_speed_m_s)
                out.append(Emit(self._mav.mission_item_reached_encode(item.seq)))
                out += self._mission_advance()
                continue
            if self._mission_phase is None:
                self._mission_target = self._item_target_ned(item)
                self._mission_hold_until = None
                if not self._in_air and cmd != mavlink.MAV_CMD_NAV_LAND:
                    self._mission_phase = "takeoff"
                    if cmd != mavlink.MAV_CMD_NAV_TAKEOFF:  # implicit takeoff to the first waypoint's altitude
                        self._mission_target = (s.north_m, s.east_m, self._mission_target[2])
                else:
                    self._mission_phase = "goto"
                return out
            phase = self._mission_phase
            target = self._mission_target
            if phase == "takeoff":
                if -s.down_m >= -target[2] - 0.5 and self._in_air:
                    if cmd == mavlink.MAV_CMD_NAV_TAKEOFF:
                        out.append(Emit(self._mav.mission_item_reached_encode(item.seq)))
                        out += self._mission_advance()
                        continue
                    self._mission_target = self._item_target_ned(item)
                    self._mission_phase = "goto"
                return out
            if phase == "goto":
                acc = item.param2 if cmd == mavlink.MAV_CMD_NAV_WAYPOINT and item.param2 > 0 else self._params["NAV_ACC_RAD"]
                if cmd == mavlink.MAV_CMD_NAV_LAND:
                    acc = LAND_POSITION_ACCEPT_M
                dist = math.hypot(target[0] - s.north_m, target[1] - s.east_m)
                if dist > acc or (cmd != mavlink.MAV_CMD_NAV_LAND and abs(target[2] - s.down_m) > MISSION_ALT_ACCEPT_M):
                    return out
                if cmd == mavlink.MAV_CMD_NAV_LAND:
                    self._mission_phase = "land"
                    return out
                out.append(Emit(self._mav.mission_item_reached_encode(item.seq)))
                if cmd == mavlink.MAV_CMD_NAV_LOITER_UNLIM:
                    self._mission_phase = "hold"
                    return out
                hold = item.param1 if cmd in (mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_CMD_NAV_LOITER_TIME) else 0.0
                if hold > 0:
                    self._mission_phase = "hold"
                    self._mission_hold_until = t + hold
                    return out
                out += self._mission_advance()
                continue
            if phase == "hold":
                if self._mission_hold_until is not None and t >= self._mission_hold_until:
                    out += self._mission_advance()
                    continue
                return out
            if phase == "land":
                if not self._in_air:
                    out.append(Emit(self._mav.mission_item_reached_encode(item.seq)))
                    self._mission_done = True
                    self.mode = FlightMode.LAND
                    self._land_ne = (s.north_m, s.east_m)
                    return out + [Emit(self._mission_current()), Emit(self._heartbeat())]
                return out
        return out

    def _mission_advance(self) -> list[Emit]:
        self._mission_index += 1
        self._mission_phase = None
        self._mission_hold_until = None
        self.missions.current_seq = min(self._mission_index, max(0, len(self.missions.plan(MISSION)) - 1))
        if self._mission_index < len(self.missions.plan(MISSION)):
            return [Emit(self._mission_current())]
        return []

    def _mission_finish(self, text: str) -> list[Emit]:
        self._mission_done = True
        out = [Emit(self._statustext(mavlink.MAV_SEVERITY_INFO, text)), Emit(self._mission_current())]
        self._enter_mode(FlightMode.HOLD)
        if self._in_air and any(it.has_position for it in self.missions.plan(MISSION)):
            self._hold_ned = self._mission_target  # PX4 loiters at the last waypoint
        return out + [Emit(self._heartbeat())]

    # ================================================================== telemetry =========
    def telemetry(self, wall_t: float) -> list[Emit]:
        """Streamed messages due now on every link."""
        out: list[Emit] = []
        for link, sched in self._links.items():
            for msg_id in sched.due(self.sim_time_s, wall_t):
                for m in self._builders[msg_id]():
                    out.append(Emit(m, link))
        return out

    def build(self, msg_id: int) -> list[Any]:
        """The message(s) the vehicle would send for ``msg_id`` now (empty if it cannot)."""
        builder = self._builders.get(msg_id)
        return builder() if builder else []

    @property
    def _time_boot_ms(self) -> int:
        return int(self.sim_time_s * 1000.0) & 0xFFFFFFFF

    def _geodetic(self) -> tuple[float, float, float]:
        cache = self._geo_cache
        if cache is not None and cache[0] == self._steps:
            return cache[1]
        s = self._state
        geo = local_to_geodetic(self._origin, s.east_m, s.north_m, -s.down_m)
        self._geo_cache = (self._steps, geo)
        return geo

    def _base_mode(self) -> int:
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
        if self.mode is not FlightMode.POSCTL:
            base |= mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
        if self.mode not in (FlightMode.POSCTL, FlightMode.OFFBOARD):
            base |= mavlink.MAV_MODE_FLAG_AUTO_ENABLED
        if self.armed:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        return base

    def _heartbeat(self) -> Any:
        status = mavlink.MAV_STATE_ACTIVE if self.armed else mavlink.MAV_STATE_STANDBY
        return self._mav.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, self._base_mode(),
                                          self.mode.custom_mode, status, 3)

    def _sys_status(self) -> Any:
        present = SENSORS_OK | PREARM_CHECK
        health = SENSORS_OK | (PREARM_CHECK if self._armable() else 0)
        e = self._energy
        return self._mav.sys_status_encode(
            present, present, health, 100, int(e.voltage_v(self.battery_pct) * 1000),
            int(e.current_a(self._drain_pct_s) * 100), int(round(self.battery_pct)), 0, 0, 0, 0, 0, 0)

    def _extended_sys_state(self) -> Any:
        return self._mav.extended_sys_state_encode(mavlink.MAV_VTOL_STATE_UNDEFINED, int(self.landed_state))

    def _local_position_ned(self) -> Any:
        s = self._state
        return self._mav.local_position_ned_encode(self._time_boot_ms, s.north_m, s.east_m, s.down_m,
                                                   s.vn_m_s, s.ve_m_s, s.vd_m_s)

    def _global_position_int(self) -> Any:
        s = self._state
        lat, lon, alt = self._geodetic()
        hdg = int(round(math.degrees(s.yaw_rad) * 100.0)) % 36000

        def cm_s(v: float) -> int:
            return int(_clip(round(v * 100.0), -32767, 32767))

        return self._mav.global_position_int_encode(
            self._time_boot_ms, int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(alt * 1000.0)),
            int(round(-s.down_m * 1000.0)), cm_s(s.vn_m_s), cm_s(s.ve_m_s), cm_s(s.vd_m_s), hdg)

    def _attitude(self) -> Any:
        s = self._state
        an, ae = self._accel_ned
        c, sn = math.cos(s.yaw_rad), math.sin(s.yaw_rad)
        a_fwd, a_right = c * an + sn * ae, -sn * an + c * ae
        # A multicopter tilts into its acceleration: nose down to speed up, bank into a turn.
        pitch = -math.atan2(a_fwd, GRAVITY_M_S2)
        roll = math.atan2(a_right, GRAVITY_M_S2)
        return self._mav.attitude_encode(self._time_boot_ms, roll, pitch, s.yaw_rad, 0.0, 0.0, s.yawspeed_rad_s)

    def _gps_raw_int(self) -> Any:
        s = self._state
        lat, lon, alt = self._geodetic()
        speed = s.ground_speed_m_s
        cog = int(round(math.degrees(math.atan2(s.ve_m_s, s.vn_m_s)) * 100.0)) % 36000 if speed > 0.2 else 65535
        return self._mav.gps_raw_int_encode(
            int(self.sim_time_s * 1e6), mavlink.GPS_FIX_TYPE_3D_FIX, int(round(lat * 1e7)), int(round(lon * 1e7)),
            int(round(alt * 1000.0)), 70, 100, int(round(speed * 100.0)), cog, 12,
            int(round(alt * 1000.0)), 500, 800, 200, 0, 0)

    def _home_geodetic(self) -> tuple[float, float, float]:
        n, e, d = self.home_ned
        return local_to_geodetic(self._origin, e, n, -d)

    def _home_position(self) -> Any:
        lat, lon, alt = self._home_geodetic()
        n, e, d = self.home_ned
        return self._mav.home_position_encode(int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(alt * 1000.0)),
                                              n, e, d, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, int(self.sim_time_s * 1e6))

    def _gps_global_origin(self) -> Any:
        o = self._origin
        return self._mav.gps_global_origin_encode(int(round(o.lat_deg * 1e7)), int(round(o.lon_deg * 1e7)),
                                                  int(round(o.alt_m * 1000.0)), int(self.sim_time_s * 1e6))

    def _battery_status(self) -> Any:
        e = self._energy
        frac = self.battery_pct / 100.0
        p = self._params
        charge = (mavlink.MAV_BATTERY_CHARGE_STATE_EMERGENCY if frac <= p["BAT_EMERGEN_THR"]
                  else mavlink.MAV_BATTERY_CHARGE_STATE_CRITICAL if frac <= p["BAT_CRIT_THR"]
                  else mavlink.MAV_BATTERY_CHARGE_STATE_LOW if frac <= p["BAT_LOW_THR"]
                  else mavlink.MAV_BATTERY_CHARGE_STATE_OK)
        voltages = [int(e.voltage_v(self.battery_pct) * 1000)] + [65535] * 9
        time_left = int(self.battery_pct / self._drain_pct_s) if self._drain_pct_s > 0 else 0
        return self._mav.battery_status_encode(
            0, mavlink.MAV_BATTERY_FUNCTION_ALL, mavlink.MAV_BATTERY_TYPE_LIPO, 32767, voltages,
            int(e.current_a(self._drain_pct_s) * 100), int(e.consumed_mah(self.spec.battery_pct, self.battery_pct)), -1,
            int(round(self.battery_pct)), time_left, charge)

    def _mission_current(self) -> Any:
        n = len(self.missions.plan(MISSION))
        if n == 0:
            state = mavlink.MISSION_STATE_NO_MISSION
        elif self._mission_done:
            state = mavlink.MISSION_STATE_COMPLETE
        elif self.mode is FlightMode.MISSION:
            state = mavlink.MISSION_STATE_ACTIVE
        elif self._mission_started:
            state = mavlink.MISSION_STATE_PAUSED
        else:
            state = mavlink.MISSION_STATE_NOT_STARTED
        seq = min(self._mission_index, max(0, n - 1))
        return self._mav.mission_current_encode(seq, n, state, 1 if self.mode is FlightMode.MISSION else 0)

    def _adsb_vehicles(self) -> list[Any]:
        out = []
        t = self.sim_time_s
        for k, o in enumerate(self._world.obstacles):
            if not o.is_moving:
                continue
            cx, cy = o.center_at(t)
            ve, vn = o.motion.velocity_at(t)
            lat, lon, alt = local_to_geodetic(self._origin, cx, cy, 0.0)
            speed = math.hypot(vn, ve)
            heading = int(round(math.degrees(math.atan2(ve, vn)) * 100.0)) % 36000
            out.append(self._mav.adsb_vehicle_encode(
                ADSB_ICAO_BASE + k, int(round(lat * 1e7)), int(round(lon * 1e7)),
                mavlink.ADSB_ALTITUDE_TYPE_GEOMETRIC, int(round(alt * 1000.0)), heading,
                int(round(speed * 100.0)) & 0xFFFF, 0, o.id[:8].encode("ascii", "replace"),
                mavlink.ADSB_EMITTER_TYPE_POINT_OBSTACLE, 0, ADSB_FLAGS, 0))
        return out

    def _autopilot_version(self) -> Any:
        uid = (0x53494D << 40) | self.system_id  # "SIM" + system id: unique per vehicle
        return self._mav.autopilot_version_encode(
            CAPABILITIES, PX4_FLIGHT_SW_VERSION, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, uid,
            [self.system_id] + [0] * 17)

    def _statustext(self, severity: int, text: str) -> Any:
        return self._mav.statustext_encode(severity, text[:50].encode("ascii", "replace"))
