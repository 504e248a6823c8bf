"""The Vehicle port in process: the SITL stub's sans-I/O vehicles driven directly. No sockets, no MAVSDK.

    async with open_inprocess_fleet(mission) as fleet:
        a = fleet.vehicle("a")            # an InProcessVehicle: the whole Vehicle port
        await a.wait_ready(5.0)
        await a.arm()

One :class:`InProcessFleet` owns a :class:`~sim_bridge.vehicle.SimVehicle` per mission vehicle
and one sim clock. Its driver task advances every vehicle together by one physics step per event
loop turn (``speedup=None``: as fast as the loop turns) or paced at a speed factor by the stub's
own :class:`~sim_bridge.clock.SimClock`; the moving obstacles' ADSB_VEHICLE reports come from the
same clock, as in the stub. The companion's tasks get a turn after every step, so a setpoint
computed from a sample reaches the vehicle before the next step: the flight does not depend on
the machine's load and is repeatable.

pymavlink is only the codec. Everything the companion sends is a real ``MAVLink_*_message`` built
and packed by the companion's own ``MAVLink`` encoder (system 245, component 190, as MAVSDK's
ground station); ``SimVehicle.handle`` answers it at once and its replies (COMMAND_ACK, mission
protocol, PARAM_VALUE, the heartbeat after a mode change) are read from the messages it emits,
exactly as the streamed telemetry is. ``wire=True`` also packs and parses every message in both
directions, as the UDP path does. Frames convert only through :mod:`uav_model.frames`.

What differs from the socket path (see docs/companion.md): no MAVSDK in between, so there is no
20 Hz setpoint resend of MAVSDK's offboard plugin (setpoints reach the vehicle only when the
companion sends them); commands are answered in the same turn; streams are paced in sim time only
(no wall-clock caps); no link faults, no GCS link, no .tlog.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import AsyncIterator, Iterable, Sequence
from contextlib import asynccontextmanager
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from uav_model import frames
from companion.errors import CommandRefused, MissionUploadError, TelemetryLost, VehicleNotReady
from uav_model.mission import Mission, VehicleSpec
from companion.vehicle.board import BoardReaders, VehicleBoard
from companion.vehicle.convert import traffic_velocity_enu
from companion.vehicle.port import (FlightMode, GeoWaypoint, LandedState, TrafficReport, Vehicle,
                                    VelocityYawRateSetpoint)
from sim_bridge.clock import SimClock
from sim_bridge.energy import EnergyModel
from sim_bridge.px4 import Px4AutoSubMode, Px4MainMode, decode_custom_mode
from sim_bridge.streams import API_RATES_HZ, StreamProfile
from sim_bridge.vehicle import Emit, SimVehicle

log = logging.getLogger(__name__)

LINK = "api"  # the one link each in-process vehicle has: the companion's
PEER = "companion"
GCS_SYSTEM_ID = 245  # MAVSDK's ground-station identity, so the vehicles see the same partner
GCS_COMPONENT_ID = mavlink.MAV_COMP_ID_MISSIONPLANNER
# The stub's API stream rates, in sim time only (a wall-clock cap would starve a fast sim), less
# the streams this link's one reader never reads: building them is a third of the telemetry cost.
UNREAD_STREAMS = frozenset({mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, mavlink.MAVLINK_MSG_ID_GPS_RAW_INT,
                            mavlink.MAVLINK_MSG_ID_MISSION_CURRENT})
INPROCESS_PROFILE = StreamProfile(
    MappingProxyType({k: hz for k, hz in API_RATES_HZ.items() if k not in UNREAD_STREAMS}), max_wall_rate_hz=0.0)
# SET_POSITION_TARGET_LOCAL_NED: body velocity + yaw rate (position, acceleration and yaw ignored).
BODY_VELOCITY_YAW_RATE_MASK = (
    mavlink.POSITION_TARGET_TYPEMASK_X_IGNORE | mavlink.POSITION_TARGET_TYPEMASK_Y_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_Z_IGNORE | mavlink.POSITION_TARGET_TYPEMASK_AX_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_AY_IGNORE | mavlink.POSITION_TARGET_TYPEMASK_AZ_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_YAW_IGNORE)
SENSORS_REQUIRED = {  # MAVSDK's health_all_ok reads these SYS_STATUS bits
    "gyrometer": mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO,
    "accelerometer": mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL,
    "magnetometer": mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG,
    "gps": mavlink.MAV_SYS_STATUS_SENSOR_GPS,
}

# PX4 (main, sub) modes of the port's flight modes; sub modes only mean something under AUTO.
_PX4_MODES: dict[FlightMode, tuple[int, int]] = {
    FlightMode.READY: (Px4MainMode.AUTO, Px4AutoSubMode.READY),
    FlightMode.TAKEOFF: (Px4MainMode.AUTO, Px4AutoSubMode.TAKEOFF),
    FlightMode.HOLD: (Px4MainMode.AUTO, Px4AutoSubMode.LOITER),
    FlightMode.MISSION: (Px4MainMode.AUTO, Px4AutoSubMode.MISSION),
    FlightMode.RETURN_TO_LAUNCH: (Px4MainMode.AUTO, Px4AutoSubMode.RTL),
    FlightMode.LAND: (Px4MainMode.AUTO, Px4AutoSubMode.LAND),
    FlightMode.OFFBOARD: (Px4MainMode.OFFBOARD, Px4AutoSubMode.NONE),
    FlightMode.POSCTL: (Px4MainMode.POSCTL, Px4AutoSubMode.NONE),
}
_MODES = {pair: mode for mode, pair in _PX4_MODES.items()}
_LANDED = {
    mavlink.MAV_LANDED_STATE_ON_GROUND: LandedState.ON_GROUND, mavlink.MAV_LANDED_STATE_IN_AIR: LandedState.IN_AIR,
    mavlink.MAV_LANDED_STATE_TAKEOFF: LandedState.TAKING_OFF, mavlink.MAV_LANDED_STATE_LANDING: LandedState.LANDING,
}
# COMMAND_ACK results under the names MAVSDK gives them, and whether a retry may help.
_RESULTS: dict[int, tuple[str, bool]] = {
    mavlink.MAV_RESULT_TEMPORARILY_REJECTED: ("COMMAND_DENIED", False),
    mavlink.MAV_RESULT_DENIED: ("COMMAND_DENIED", False),
    mavlink.MAV_RESULT_UNSUPPORTED: ("UNSUPPORTED", False),
    mavlink.MAV_RESULT_FAILED: ("UNKNOWN", True),
}


def _mode_of(custom_mode: int) -> FlightMode:
    main, sub = decode_custom_mode(custom_mode)
    return _MODES.get((main, sub if main == Px4MainMode.AUTO else 0), FlightMode.OTHER)


def _text(value: bytes | str) -> str:
    """A char[] field: bytes on a message object as built, str once parsed from the wire."""
    text = value.decode("ascii", "replace") if isinstance(value, bytes) else str(value)
    return text.split("\x00", 1)[0].strip()


@dataclass(frozen=True)
class InProcessOptions:
    """How the in-process sim runs. ``speedup`` None: one physics step per event-loop turn."""

    speedup: float | None = None
    physics_dt_s: float = 0.02
    speed_headroom: float = 1.0  # vehicle speed limit = mission speed * headroom, as SimOptions
    energy: EnergyModel = field(default_factory=EnergyModel)
    wire: bool = False  # pack and parse every message both ways (slower; exercises the byte codec)

    def __post_init__(self) -> None:
        SimClock(1.0 if self.speedup is None else self.speedup, self.physics_dt_s, 0.0)  # ClockError if unusable


class _Codec:
    """One direction of the in-process link: packs with the sender's ids; with ``wire``, re-parses."""

    def __init__(self, system_id: int, component_id: int, wire: bool):
        self._encoder = mavlink.MAVLink(None, system_id, component_id)
        self._parser = mavlink.MAVLink(None, 0, 0) if wire else None
        if self._parser is not None:
            self._parser.robust_parsing = True

    @property
    def factory(self) -> mavlink.MAVLink:
        return self._encoder

    def carry(self, msg: Any) -> list[Any]:
        """What arrives at the other end: the packed message itself, or what the bytes parse to."""
        buf = msg.pack(self._encoder)  # sets the header (source ids, sequence) as on the wire
        self._encoder.seq = (self._encoder.seq + 1) % 256
        if self._parser is None:
            return [msg]
        return [m for m in self._parser.parse_buffer(buf) or [] if m.get_type() != "BAD_DATA"]


class InProcessVehicle(BoardReaders):
    """The Vehicle port over one in-process SimVehicle. Build through :func:`open_inprocess_fleet`."""

    def __init__(self, fleet: InProcessFleet, sim: SimVehicle, origin: frames.GeoOrigin, wire: bool):
        self._fleet = fleet
        self._sim = sim
        self._origin = origin
        self._board = VehicleBoard(sim.name)
        self._up = _Codec(GCS_SYSTEM_ID, GCS_COMPONENT_ID, wire)  # companion -> vehicle
        self._down = _Codec(sim.system_id, sim.component_id, wire) if wire else None  # vehicle -> companion
        self._sensors_ok = False
        self._home_seen = False
        self._position_seen = False
        # The pose's two halves, paired as the MAVSDK adapter pairs them (attitude stamp + position).
        self._att: tuple[float, float] | None = None  # (t_sim_s, heading_enu_rad)
        self._pos: tuple[float, float, float, float, float] | None = None  # x, y, alt, vx, vy
        self._att_fresh = False
        self._pos_fresh = False

    # -- port: readers --------------------------------------------------------------------
    @property
    def name(self) -> str:
        return self._sim.name

    @property
    def system_id(self) -> int:
        return self._sim.system_id

    @property
    def clock_follows_event_loop(self) -> bool:
        """True when free-running: sim time moves only when the event loop turns, so CPU work
        done inline costs no sim time while work in a thread lets the sim fly on without us."""
        return self._fleet.options.speedup is None

    @property
    def sim(self) -> SimVehicle:
        """The simulated autopilot itself (truth: collisions, offboard losses, parameters)."""
        return self._sim

    def sim_rate(self) -> float | None:
        # Free-running, sim time only moves when the companion yields: there is no rate a wall
        # bound could trust (a descheduled process would look like a dead link), so the pilot
        # falls back to its generous 1x bounds. Paced, it is measured as on the socket path.
        return None if self._fleet.options.speedup is None else self._board.sim_rate

    async def wait_ready(self, timeout_s: float) -> None:
        """Health all OK (gyro/accel/mag/GPS sensors, global position, home) and a first pose."""
        try:
            await self._board.wait_until(lambda s, p: s.health_ok and p is not None, timeout_s,
                                         "healthy status and position")
        except TelemetryLost:  # say what is missing, as the MAVSDK adapter does
            missing = [what for what, ok in (("sensors", self._sensors_ok), ("home position", self._home_seen),
                                             ("global position", self._position_seen)) if not ok]
            detail = f"; not ok: {', '.join(missing)}" if missing else ""
            raise VehicleNotReady(f"not healthy within {timeout_s:g} s{detail}", vehicle=self.name) from None

    # -- port: commands -------------------------------------------------------------------
    async def arm(self) -> None:
        await self._command("arm", mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)

    async def disarm(self) -> None:
        await self._command("disarm", mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0.0)

    async def takeoff(self, alt_rel_m: float) -> None:
        # As MAVSDK: MIS_TAKEOFF_ALT through the param protocol, then NAV_TAKEOFF without an altitude.
        await self._set_param("set takeoff altitude", "MIS_TAKEOFF_ALT", float(alt_rel_m))
        nan = math.nan
        await self._command("takeoff", mavlink.MAV_CMD_NAV_TAKEOFF, nan, nan, nan, nan, nan, nan, nan)

    async def start_offboard(self, first: VelocityYawRateSetpoint) -> None:
        # PX4 refuses OFFBOARD unless setpoints are already flowing: send one first.
        await self.send_setpoint(first)
        await self.set_mode(FlightMode.OFFBOARD, "offboard start")

    async def send_setpoint(self, setpoint: VelocityYawRateSetpoint) -> None:
        values = (setpoint.forward_m_s, setpoint.yaw_rate_enu_rad_s, setpoint.climb_m_s)
        if not all(math.isfinite(v) for v in values):
            raise CommandRefused("offboard setpoint", "INVALID", vehicle=self.name, detail=f"not finite: {setpoint}")
        forward_m_s, right_m_s, down_m_s = float(setpoint.forward_m_s), 0.0, float(-setpoint.climb_m_s)
        yawspeed = frames.enu_yaw_rate_to_ned(float(setpoint.yaw_rate_enu_rad_s))
        msg = self._up.factory.set_position_target_local_ned_encode(
            self._time_boot_ms(), self.system_id, self._sim.component_id, mavlink.MAV_FRAME_BODY_NED,
            BODY_VELOCITY_YAW_RATE_MASK, 0.0, 0.0, 0.0, forward_m_s, right_m_s, down_m_s, 0.0, 0.0, 0.0,
            0.0, yawspeed)
        await self._absorb(self._exchange(msg))

    async def hold(self) -> None:
        await self.set_mode(FlightMode.HOLD, "hold")

    async def land(self) -> None:
        nan = math.nan
        await self._command("land", mavlink.MAV_CMD_NAV_LAND, nan, nan, nan, nan, nan, nan, nan)

    async def set_mode(self, mode: FlightMode, what: str = "set mode") -> None:
        """DO_SET_MODE to a PX4 custom mode (the port's hold and offboard start use it)."""
        if mode not in _PX4_MODES:
            raise CommandRefused(what, "UNSUPPORTED", vehicle=self.name, detail=f"no PX4 mode for {mode.value}")
        main, sub = _PX4_MODES[mode]
        await self._command(what, mavlink.MAV_CMD_DO_SET_MODE, float(mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED),
                            float(main), float(sub))

    async def upload_route(self, waypoints: Sequence[GeoWaypoint], acceptance_radius_m: float) -> None:
        """The MAVLink mission upload: COUNT, then one MISSION_ITEM_INT per request, until the ACK."""
        if not waypoints:
            raise MissionUploadError("empty route", vehicle=self.name)
        for i, w in enumerate(waypoints):  # what MISSION_ITEM_INT cannot carry (int32 degE7) never leaves
            if not all(math.isfinite(v) and abs(v) * 1e7 < 2**31 for v in (w.lat_deg, w.lon_deg)):
                raise MissionUploadError(f"waypoint {i}: lat/lon {w.lat_deg}, {w.lon_deg} cannot be encoded",
                                         vehicle=self.name)
        f = self._up.factory
        items = [f.mission_item_int_encode(
            self.system_id, self._sim.component_id, i, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
            mavlink.MAV_CMD_NAV_WAYPOINT, 1 if i == 0 else 0, 1, 0.0, float(acceptance_radius_m), 0.0, math.nan,
            int(round(w.lat_deg * 1e7)), int(round(w.lon_deg * 1e7)), float(w.alt_rel_m),
            mavlink.MAV_MISSION_TYPE_MISSION) for i, w in enumerate(waypoints)]
        reply = await self._mission_reply(f.mission_count_encode(self.system_id, self._sim.component_id, len(items),
                                                                 mavlink.MAV_MISSION_TYPE_MISSION), "mission upload")
        for _ in range(len(items) + 1):  # one request per item, then the ACK: anything more is a bug
            kind = reply.get_type()
            if kind == "MISSION_ACK":
                if reply.type != mavlink.MAV_MISSION_ACCEPTED:
                    raise MissionUploadError(f"mission upload: {_mission_result(reply.type)}", vehicle=self.name)
                return
            if kind not in ("MISSION_REQUEST_INT", "MISSION_REQUEST") or not 0 <= reply.seq < len(items):
                break
            reply = await self._mission_reply(items[reply.seq], "mission upload")
        # End the vehicle's side of the transfer, as a GCS cancels one (MISSION_ACK with an error).
        await self._absorb(self._exchange(f.mission_ack_encode(
            self.system_id, self._sim.component_id, mavlink.MAV_MISSION_OPERATION_CANCELLED,
            mavlink.MAV_MISSION_TYPE_MISSION)))
        raise MissionUploadError(f"mission upload: unexpected {reply.get_type()}", vehicle=self.name)

    async def download_route(self) -> tuple[GeoWaypoint, ...]:
        f = self._up.factory
        target = (self.system_id, self._sim.component_id)
        mtype = mavlink.MAV_MISSION_TYPE_MISSION
        count = await self._mission_reply(f.mission_request_list_encode(*target, mtype), "mission download")
        if count.get_type() != "MISSION_COUNT":
            raise MissionUploadError(f"mission download: {_describe(count)}", vehicle=self.name)
        out: list[GeoWaypoint] = []
        for seq in range(count.count):
            item = await self._mission_reply(f.mission_request_int_encode(*target, seq, mtype), "mission download")
            if item.get_type() != "MISSION_ITEM_INT" or item.seq != seq:
                raise MissionUploadError(f"mission download: {_describe(item)} for item {seq}", vehicle=self.name)
            if item.command == mavlink.MAV_CMD_NAV_WAYPOINT:
                out.append(GeoWaypoint(lat_deg=item.x / 1e7, lon_deg=item.y / 1e7, alt_rel_m=float(item.z)))
        await self._absorb(self._exchange(f.mission_ack_encode(*target, mavlink.MAV_MISSION_ACCEPTED, mtype)))
        return tuple(out)

    # -- the link -------------------------------------------------------------------------
    def _time_boot_ms(self) -> int:
        return int(self._fleet.sim_time_s * 1000.0) & 0xFFFFFFFF

    def _exchange(self, msg: Any) -> list[Any]:
        """Deliver one message to the vehicle; what it emits in answer, as the companion receives it."""
        out: list[Any] = []
        for m in self._up.carry(msg):
            out += self.receive(self._sim.handle(m, LINK, PEER))
        return out

    def receive(self, emits: Iterable[Emit]) -> list[Any]:
        """The vehicle's emitted messages that reach the companion (all of them: it is the only peer)."""
        if self._down is None:
            return [e.msg for e in emits if e.link in (None, LINK)]
        out: list[Any] = []
        for e in emits:
            if e.link in (None, LINK):
                out += self._down.carry(e.msg)
        return out

    async def _command(self, what: str, command: int, *params: float) -> None:
        p = (list(params) + [0.0] * 7)[:7]
        msg = self._up.factory.command_long_encode(self.system_id, self._sim.component_id, command, 0, *p)
        replies = self._exchange(msg)
        await self._absorb(replies)
        acks = [r for r in replies if r.get_type() == "COMMAND_ACK" and r.command == command]
        if not acks:
            raise CommandRefused(what, "TIMEOUT", vehicle=self.name, retryable=True, detail="no COMMAND_ACK")
        result = acks[-1].result
        if result in (mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_IN_PROGRESS):
            return
        name, retryable = _RESULTS.get(result, ("UNKNOWN", True))
        raise CommandRefused(what, name, vehicle=self.name, retryable=retryable)

    async def _set_param(self, what: str, name: str, value: float) -> None:
        msg = self._up.factory.param_set_encode(self.system_id, self._sim.component_id, name.encode("ascii"),
                                                value, mavlink.MAV_PARAM_TYPE_REAL32)
        replies = self._exchange(msg)
        await self._absorb(replies)
        echoes = [r for r in replies if r.get_type() == "PARAM_VALUE" and _text(r.param_id) == name]
        if not echoes:
            raise CommandRefused(what, "TIMEOUT", vehicle=self.name, retryable=True,
                                 detail=f"no PARAM_VALUE for {name}")
        if not math.isclose(echoes[-1].param_value, value, rel_tol=1e-6, abs_tol=1e-6):
            raise CommandRefused(what, "PARAMETER_ERROR", vehicle=self.name,
                                 detail=f"{name} stayed {echoes[-1].param_value:g}, asked {value:g}")

    async def _mission_reply(self, msg: Any, what: str) -> Any:
        replies = self._exchange(msg)
        await self._absorb(replies)
        mission = [r for r in replies if r.get_type() in ("MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK",
                                                           "MISSION_COUNT", "MISSION_ITEM_INT")]
        if not mission:
            raise MissionUploadError(f"{what}: the vehicle did not answer {msg.get_type()}", vehicle=self.name)
        return mission[-1]

    # -- telemetry ------------------------------------------------------------------------
    async def _absorb(self, msgs: Sequence[Any]) -> None:
        """Fold a batch of the vehicle's messages into the board: one status update, one pose."""
        if not msgs:
            return
        board = self._board
        status = board.status()
        changes: dict[str, Any] = {}
        t_att: float | None = None
        adsb: list[Any] = []
        for m in msgs:
            kind = m.get_type()
            if kind == "ATTITUDE":
                t_att = m.time_boot_ms / 1000.0
                self._att = (t_att, frames.ned_yaw_to_enu_heading(m.yaw))
                self._att_fresh = True
            elif kind == "GLOBAL_POSITION_INT":
                self._position_seen = True
                x, y, _ = frames.geodetic_to_local(self._origin, m.lat / 1e7, m.lon / 1e7)
                east, north, _ = frames.ned_to_enu(m.vx / 100.0, m.vy / 100.0, m.vz / 100.0)
                self._pos = (x, y, m.relative_alt / 1000.0, east, north)
                self._pos_fresh = True
            elif kind == "HEARTBEAT":
                changes["mode"] = _mode_of(m.custom_mode)
                changes["armed"] = bool(m.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
            elif kind == "EXTENDED_SYS_STATE":
                changes["landed"] = _LANDED.get(m.landed_state, LandedState.UNKNOWN)
            elif kind == "SYS_STATUS":
                need = sum(SENSORS_REQUIRED.values())
                self._sensors_ok = all(getattr(m, f) & need == need for f in (
                    "onboard_control_sensors_present", "onboard_control_sensors_enabled",
                    "onboard_control_sensors_health"))
            elif kind == "HOME_POSITION":
                self._home_seen = True
            elif kind == "BATTERY_STATUS":
                changes["battery_pct"] = float(m.battery_remaining) if m.battery_remaining >= 0 else None
            elif kind == "ADSB_VEHICLE":
                adsb.append(m)
            elif kind == "STATUSTEXT":
                log.info("%s: %s", self.name, _text(m.text))
        changes["health_ok"] = self._sensors_ok and self._home_seen and self._position_seen
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

    async def _traffic(self, m: Any) -> None:
        callsign = _text(m.callsign)
        if not callsign or not m.flags & mavlink.ADSB_FLAGS_VALID_COORDS:
            return
        x, y, _ = frames.geodetic_to_local(self._origin, m.lat / 1e7, m.lon / 1e7)
        vx, vy = traffic_velocity_enu(m.heading / 100.0, m.hor_velocity / 100.0)
        t_sim = self._board.latest_clock_s if self._board.latest_clock_s is not None else math.nan
        await self._board.put_traffic(TrafficReport(callsign=callsign, x_east_m=x, y_north_m=y, vx_east_m_s=vx,
                                                    vy_north_m_s=vy, t_sim_s=t_sim,
                                                    t_wall_s=time.monotonic(), via=self.name))


def _mission_result(code: int) -> str:
    entry = mavlink.enums["MAV_MISSION_RESULT"].get(code)
    return entry.name if entry is not None else f"MAV_MISSION_RESULT {code}"


def _describe(msg: Any) -> str:
    if msg.get_type() == "MISSION_ACK":
        return _mission_result(msg.type)
    return f"unexpected {msg.get_type()}"


class InProcessFleet:
    """Every vehicle of a mission on one sim clock, driven from asyncio. Use :func:`open_inprocess_fleet`.

    Without the driver (a bare ``InProcessFleet``), ``await fleet.step()`` advances it by hand: the
    vehicles then send nothing until stepped.
    """

    def __init__(self, mission: Mission, options: InProcessOptions | None = None):
        self.mission = mission
        self.options = options or InProcessOptions()
        o = self.options
        self._vehicles: dict[str, InProcessVehicle] = {}
        for spec in mission.vehicles:
            sim = SimVehicle(spec, mission, speed_headroom=o.speed_headroom, energy=o.energy)
            sim.add_link(LINK, INPROCESS_PROFILE)
            self._vehicles[spec.name] = InProcessVehicle(self, sim, mission.origin, o.wire)
        self._steps = 0

    @property
    def sim_time_s(self) -> float:
        return self._steps * self.options.physics_dt_s

    @property
    def steps(self) -> int:
        return self._steps

    def vehicle(self, name: str) -> InProcessVehicle:
        try:
            return self._vehicles[name]
        except KeyError:
            raise KeyError(f"the mission has no vehicle {name!r} (vehicles: {', '.join(self._vehicles)})") from None

    @property
    def vehicles(self) -> tuple[InProcessVehicle, ...]:
        return tuple(self._vehicles.values())

    def connections(self) -> dict[str, str]:
        """A label per vehicle where the socket path has a URL (for reports and summary.json)."""
        return {name: f"inprocess://{v.system_id}" for name, v in self._vehicles.items()}

    @asynccontextmanager
    async def open_vehicle(self, spec: VehicleSpec, url: str = "") -> AsyncIterator[Vehicle]:
        """The runner's per-vehicle opener: the vehicle is already there while the fleet runs."""
        yield self.vehicle(spec.name)

    async def step(self) -> None:
        """Advance every vehicle by one physics step, then hand each its messages of this step."""
        dt = self.options.physics_dt_s
        stepped = [(v, v.sim.step(dt)) for v in self._vehicles.values()]
        self._steps += 1
        t = self.sim_time_s
        for v, emits in stepped:
            # Wall-clock duties run on sim time: in process there is no other clock to honour.
            emits += v.sim.poll(t)
            emits += v.sim.telemetry(t)
            await v._absorb(v.receive(emits))

    async def run(self) -> None:
        """The driver: step forever, giving the companion's tasks a turn after every step."""
        speedup = self.options.speedup
        if speedup is None:
            while True:
                await self.step()
                await asyncio.sleep(0)
        loop = asyncio.get_running_loop()
        clock = SimClock(speedup, self.options.physics_dt_s, loop.time())
        while True:
            due = clock.steps_due(loop.time())
            for _ in range(due):
                clock.advance()
                await self.step()
                await asyncio.sleep(0)
            if not due:
                await asyncio.sleep(max(0.0, clock.wall_of_next_step() - loop.time()))


@asynccontextmanager
async def open_inprocess_fleet(mission: Mission, options: InProcessOptions | None = None
                               ) -> AsyncIterator[InProcessFleet]:
    """Build the mission's vehicles and run their sim clock while the context is open."""
    fleet = InProcessFleet(mission, options)
    try:
        async with asyncio.TaskGroup() as tg:
            driver = tg.create_task(fleet.run(), name="inprocess-sim")
            try:
                yield fleet
            finally:
                driver.cancel()
    except BaseExceptionGroup as group:
        # The driver only ends by cancellation: hand the caller's own error back unwrapped.
        if len(group.exceptions) == 1:
            raise group.exceptions[0] from None
        raise

