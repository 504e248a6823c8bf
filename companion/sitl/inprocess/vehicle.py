"""The Vehicle port over one in-process :class:`~sim_bridge.vehicle.SimVehicle`: commands, the mission
protocol and parameters as real MAVLink messages, answered in the same turn."""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING, Any

from pymavlink.dialects.v20 import common as mavlink

from uav_model import frames
from companion.errors import CommandRefused, MissionUploadError, TelemetryLost, VehicleNotReady
from companion.sitl.inprocess.link import (BODY_VELOCITY_YAW_RATE_MASK, COMMAND_RESULTS, LINK, PEER, PX4_MODES, Codec,
                                           describe, int32_bits, mission_result, param_value, text_field)
from companion.sitl.inprocess.telemetry import TelemetryIntake
from companion.vehicle.board import BoardReaders, VehicleBoard
from companion.vehicle.convert import MAV_FRAME_GLOBAL, FenceItem, fence_items, fence_zones
from companion.vehicle.port import FlightMode, GeoFenceZone, GeoWaypoint, VelocityYawRateSetpoint
from sim_bridge.vehicle.px4 import COMPANION_SYSTEM_ID, GCS_COMPONENT_ID
from sim_bridge.vehicle import Emit, SimVehicle

if TYPE_CHECKING:
    from companion.sitl.inprocess.fleet import InProcessFleet


class InProcessVehicle(BoardReaders):
    """The Vehicle port over one in-process SimVehicle. Build through :func:`open_inprocess_fleet`."""

    def __init__(self, fleet: InProcessFleet, sim: SimVehicle, origin: frames.GeoOrigin, wire: bool):
        self._fleet = fleet
        self._sim = sim
        self._origin = origin
        self._board = VehicleBoard(sim.name)
        self._up = Codec(COMPANION_SYSTEM_ID, GCS_COMPONENT_ID, wire)  # companion -> vehicle, as MAVSDK sends
        self._down = Codec(sim.system_id, sim.component_id, wire) if wire else None  # vehicle -> companion
        self._intake = TelemetryIntake(self._board, origin, sim.name)

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
            missing = self._intake.missing()
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
        await self._intake.absorb(self._exchange(msg))

    async def hold(self) -> None:
        await self.set_mode(FlightMode.HOLD, "hold")

    async def land(self) -> None:
        nan = math.nan
        await self._command("land", mavlink.MAV_CMD_NAV_LAND, nan, nan, nan, nan, nan, nan, nan)

    async def set_mode(self, mode: FlightMode, what: str = "set mode") -> None:
        """DO_SET_MODE to a PX4 custom mode (the port's hold and offboard start use it)."""
        if mode not in PX4_MODES:
            raise CommandRefused(what, "UNSUPPORTED", vehicle=self.name, detail=f"no PX4 mode for {mode.value}")
        main, sub = PX4_MODES[mode]
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
        await self._upload(items, mavlink.MAV_MISSION_TYPE_MISSION, "mission upload")

    async def download_route(self) -> tuple[GeoWaypoint, ...]:
        items = await self._download(mavlink.MAV_MISSION_TYPE_MISSION, "mission download")
        return tuple(GeoWaypoint(lat_deg=it.x / 1e7, lon_deg=it.y / 1e7, alt_rel_m=float(it.z))
                     for it in items if it.command == mavlink.MAV_CMD_NAV_WAYPOINT)

    async def upload_fence(self, zones: Sequence[GeoFenceZone]) -> None:
        """The geofence as a FENCE plan, through the same mission protocol as the route."""
        f = self._up.factory
        mtype = mavlink.MAV_MISSION_TYPE_FENCE
        items = [f.mission_item_int_encode(self.system_id, self._sim.component_id, i, MAV_FRAME_GLOBAL, it.command,
                                           0, 1, it.param1, 0.0, 0.0, 0.0, it.lat_e7, it.lon_e7, 0.0, mtype)
                 for i, it in enumerate(fence_items(zones))]
        await self._upload(items, mtype, "geofence upload")

    async def download_fence(self) -> tuple[GeoFenceZone, ...]:
        items = await self._download(mavlink.MAV_MISSION_TYPE_FENCE, "geofence download")
        return fence_zones([FenceItem(int(it.command), float(it.param1), int(it.x), int(it.y)) for it in items])

    async def _upload(self, items: Sequence[Any], mtype: int, what: str) -> None:
        """The mission protocol's upload of one plan (mission or fence): COUNT, one item per request, the ACK."""
        f = self._up.factory
        reply = await self._mission_reply(f.mission_count_encode(self.system_id, self._sim.component_id, len(items),
                                                                 mtype), what)
        for _ in range(len(items) + 1):  # one request per item, then the ACK: anything more is a bug
            kind = reply.get_type()
            if kind == "MISSION_ACK":
                if reply.type != mavlink.MAV_MISSION_ACCEPTED:
                    raise MissionUploadError(f"{what}: {mission_result(reply.type)}", vehicle=self.name)
                return
            if kind not in ("MISSION_REQUEST_INT", "MISSION_REQUEST") or not 0 <= reply.seq < len(items):
                break
            reply = await self._mission_reply(items[reply.seq], what)
        # End the vehicle's side of the transfer, as a GCS cancels one (MISSION_ACK with an error).
        await self._intake.absorb(self._exchange(f.mission_ack_encode(
            self.system_id, self._sim.component_id, mavlink.MAV_MISSION_OPERATION_CANCELLED, mtype)))
        raise MissionUploadError(f"{what}: unexpected {reply.get_type()}", vehicle=self.name)

    async def _download(self, mtype: int, what: str) -> list[Any]:
        """The mission protocol's download of one plan: REQUEST_LIST, one REQUEST_INT per item, the ACK."""
        f = self._up.factory
        target = (self.system_id, self._sim.component_id)
        count = await self._mission_reply(f.mission_request_list_encode(*target, mtype), what)
        if count.get_type() != "MISSION_COUNT":
            raise MissionUploadError(f"{what}: {describe(count)}", vehicle=self.name)
        out: list[Any] = []
        for seq in range(count.count):
            item = await self._mission_reply(f.mission_request_int_encode(*target, seq, mtype), what)
            if item.get_type() != "MISSION_ITEM_INT" or item.seq != seq:
                raise MissionUploadError(f"{what}: {describe(item)} for item {seq}", vehicle=self.name)
            out.append(item)
        await self._intake.absorb(self._exchange(f.mission_ack_encode(*target, mavlink.MAV_MISSION_ACCEPTED, mtype)))
        return out

    # -- the link -------------------------------------------------------------------------
    def _time_boot_ms(self) -> int:
        return int(self._fleet.sim_time_s * 1000.0) & 0xFFFFFFFF

    def _exchange(self, msg: Any) -> list[Any]:
        """Deliver one message to the vehicle; what it emits in answer, as the companion receives it."""
        out: list[Any] = []
        for m in self._up.carry(msg):
            out += self.receive(self._sim.handle(m, LINK, PEER))
        return out

    async def deliver(self, emits: Iterable[Emit]) -> None:
        """Hand the vehicle's emitted messages of one step to the companion's side."""
        await self._intake.absorb(self.receive(emits))

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
        await self._intake.absorb(replies)
        acks = [r for r in replies if r.get_type() == "COMMAND_ACK" and r.command == command]
        if not acks:
            raise CommandRefused(what, "TIMEOUT", vehicle=self.name, retryable=True, detail="no COMMAND_ACK")
        result = acks[-1].result
        if result in (mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_IN_PROGRESS):
            return
        name, retryable = COMMAND_RESULTS.get(result, ("UNKNOWN", True))
        raise CommandRefused(what, name, vehicle=self.name, retryable=retryable)

    async def get_param(self, name: str) -> float | None:
        msg = self._up.factory.param_request_read_encode(self.system_id, self._sim.component_id,
                                                         name.encode("ascii"), -1)
        replies = self._exchange(msg)
        await self._intake.absorb(replies)
        values = [r for r in replies if r.get_type() == "PARAM_VALUE" and text_field(r.param_id) == name]
        return None if not values else param_value(values[-1])

    async def set_param(self, name: str, value: float) -> None:
        await self._set_param(f"set {name}", name, value)

    async def _set_param(self, what: str, name: str, value: float) -> None:
        if await self.get_param(name) is None:  # also learns its type: INT32 values travel bytewise (PX4)
            raise CommandRefused(what, "DOES_NOT_EXIST", vehicle=self.name, detail=f"no parameter {name}")
        ptype = self._intake.param_types.get(name, mavlink.MAV_PARAM_TYPE_REAL32)
        wire = int32_bits(value) if ptype == mavlink.MAV_PARAM_TYPE_INT32 else float(value)
        msg = self._up.factory.param_set_encode(self.system_id, self._sim.component_id, name.encode("ascii"),
                                                wire, ptype)
        replies = self._exchange(msg)
        await self._intake.absorb(replies)
        echoes = [r for r in replies if r.get_type() == "PARAM_VALUE" and text_field(r.param_id) == name]
        if not echoes:
            raise CommandRefused(what, "TIMEOUT", vehicle=self.name, retryable=True,
                                 detail=f"no PARAM_VALUE for {name}")
        got = param_value(echoes[-1])
        if not math.isclose(got, value, rel_tol=1e-6, abs_tol=1e-6):
            raise CommandRefused(what, "PARAMETER_ERROR", vehicle=self.name,
                                 detail=f"{name} stayed {got:g}, asked {value:g}")

    async def _mission_reply(self, msg: Any, what: str) -> Any:
        replies = self._exchange(msg)
        await self._intake.absorb(replies)
        mission = [r for r in replies if r.get_type() in ("MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK",
                                                           "MISSION_COUNT", "MISSION_ITEM_INT")]
        if not mission:
            raise MissionUploadError(f"{what}: the vehicle did not answer {msg.get_type()}", vehicle=self.name)
        return mission[-1]
