"""The Vehicle port over MAVSDK 4 (``mavsdk.asyncio``): one Mavsdk instance per vehicle.

Open with :func:`companion.vehicle.mavsdk_open.open_mavsdk_vehicle` (an async context manager).
Inside it, one task group runs the telemetry pumps (attitude, position, velocity, mode, armed,
landed state, health, battery, ADS-B traffic); leaving the context cancels them and destroys the
Mavsdk instance.

Conversions happen here and only through :mod:`uav_model.frames`: GLOBAL_POSITION_INT lat/lon
becomes mission ENU (one frame for every vehicle, whatever their homes); NED yaw becomes an ENU
heading; an ENU yaw rate becomes PX4's clockwise yawspeed. The vehicle's sim clock is the
ATTITUDE ``time_boot_ms`` that MAVSDK passes on as ``EulerAngle.timestamp_us``; position
messages carry no stamp in MAVSDK's API: the link guard reads each one's ``time_boot_ms`` on its
way (:mod:`companion.vehicle.position_stamps`); without a guard, the newest attitude's stamp.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import AsyncGenerator, Awaitable, Callable, Sequence
from typing import TypeVar

from mavsdk.asyncio.plugins.action import ActionAsync, ActionError
from mavsdk.asyncio.plugins.mission_raw import MissionItem, MissionRawAsync, MissionRawError
from mavsdk.asyncio.plugins.offboard import OffboardAsync, OffboardError
from mavsdk.asyncio.plugins.param import ParamAsync
from mavsdk.asyncio.plugins.telemetry import FlightMode as MavFlightMode, LandedState as MavLandedState
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync, TelemetryError
from mavsdk.asyncio.plugins.transponder import TransponderAsync
from mavsdk.exceptions import MavsdkError

from uav_model import frames
from companion.errors import CommandRefused, LinkError, MissionUploadError, VehicleNotReady
from companion.vehicle.board import BoardReaders, VehicleBoard
from companion.vehicle.convert import (  # shared with the in-process adapter
    MAV_FRAME_GLOBAL, FenceItem, fence_items, fence_zones, traffic_velocity_enu)
from companion.vehicle.link_guard import LinkGuard
from companion.vehicle.mavsdk_items import (MAV_MISSION_TYPE_FENCE, body_setpoint, items_to_waypoints,
                                            waypoints_to_items)
from companion.vehicle.mavsdk_params import MavsdkParams
from companion.vehicle.port import (FlightMode, GeoFenceZone, GeoWaypoint, LandedState, TrafficReport,
                                    VelocityYawRateSetpoint)

log = logging.getLogger(__name__)

T = TypeVar("T")

COMMAND_TIMEOUT_S = 5.0  # wall; MAVSDK itself retries a COMMAND_LONG for ~0.5 s x 3
# The pumped streams, in Hz of the vehicle's clock (SET_MESSAGE_INTERVAL): PX4 sends ATTITUDE at 100 Hz
# of sim time (400/s of wall at 4x), more than MAVSDK's callback queue and a loaded loop keep up with.
# 10 Hz: five samples per planner step (0.5 s). At 20 Hz PX4 at 4x still overflowed MAVSDK's callback
# queue beside a loaded machine (load 10-11: "a subscriber is not keeping up" in flight); the stub at
# 20x delivers 5 Hz of its clock anyway (its 100 Hz wall cap per stream).
STREAM_RATE_HZ = 10.0
STREAM_RATE_ATTEMPTS = 10  # a loaded machine loses acks, and MAVSDK refuses while it misses heartbeats
STREAM_RATE_RETRY_S = 2.0  # wall, between attempts
MISSION_TRANSFER_TIMEOUT_S = 30.0  # wall; the protocol has its own per-item timeouts
_RETRYABLE = frozenset({"BUSY", "TIMEOUT", "CONNECTION_ERROR", "UNKNOWN"})

_MODES = {
    MavFlightMode.READY: FlightMode.READY, MavFlightMode.TAKEOFF: FlightMode.TAKEOFF,
    MavFlightMode.HOLD: FlightMode.HOLD, MavFlightMode.MISSION: FlightMode.MISSION,
    MavFlightMode.RETURN_TO_LAUNCH: FlightMode.RETURN_TO_LAUNCH, MavFlightMode.LAND: FlightMode.LAND,
    MavFlightMode.OFFBOARD: FlightMode.OFFBOARD, MavFlightMode.POSCTL: FlightMode.POSCTL,
    MavFlightMode.UNKNOWN: FlightMode.UNKNOWN,
}
_LANDED = {
    MavLandedState.ON_GROUND: LandedState.ON_GROUND, MavLandedState.IN_AIR: LandedState.IN_AIR,
    MavLandedState.TAKING_OFF: LandedState.TAKING_OFF, MavLandedState.LANDING: LandedState.LANDING,
}


class MavsdkVehicle(BoardReaders):
    """One autopilot over its own Mavsdk instance; opened by :mod:`companion.vehicle.mavsdk_open`."""

    def __init__(self, name: str, system_id: int, system, origin: frames.GeoOrigin, guard: LinkGuard | None = None,
                 telemetry_hz: float = STREAM_RATE_HZ):
        self._name = name
        self._guard = guard
        self._telemetry_hz = telemetry_hz  # attitude, position and velocity, of the vehicle's clock
        self._system_id = system_id
        self._origin = origin
        self._board = VehicleBoard(name)
        self._telemetry = TelemetryAsync(system)
        self._action = ActionAsync(system)
        self._offboard = OffboardAsync(system)
        self._mission = MissionRawAsync(system)
        self._params = MavsdkParams(ParamAsync(system), name)
        self._transponder = TransponderAsync(system)
        # Latest halves of a pose; a sample is emitted once both have been refreshed.
        self._att: tuple[float, float] | None = None  # (t_sim_s, heading_enu_rad)
        self._pos: tuple[float, float, float] | None = None  # (x_east_m, y_north_m, alt_rel_m)
        self._vel: tuple[float, float] = (0.0, 0.0)  # (vx_east, vy_north)
        self._att_fresh = self._pos_fresh = False
        self._streams: list[AsyncGenerator] = []  # the pumps' subscriptions, closed before shutdown

    # -- port: readers --------------------------------------------------------------------
    @property
    def name(self) -> str:
        return self._name

    @property
    def system_id(self) -> int:
        return self._system_id

    async def wait_ready(self, timeout_s: float) -> None:
        """Health all OK (gyro/accel/mag, local + global position, home) and a first pose."""
        try:
            # health_all_ok includes the home position, but its own flag arrives on another
            # subscription: wait for both, or the pre-flight check reads "no home" in a race.
            await self._board.wait_until(lambda s, p: s.health_ok and s.home_ok and p is not None, timeout_s,
                                         "healthy status (MAVSDK health_all_ok), home position and position")
        except LinkError:
            detail = ""
            try:
                async with asyncio.timeout(2.0):
                    h = await self._telemetry.health()
                bad = [k for k, v in vars(h).items() if v is False]
                detail = f"; not ok: {', '.join(bad)}" if bad else ""
            except (TimeoutError, TelemetryError):
                pass
            raise VehicleNotReady(f"not healthy within {timeout_s:g} s{detail}", vehicle=self._name) from None

    # -- port: commands -------------------------------------------------------------------
    async def _command(self, command: str, call: Callable[[], Awaitable[T]],
                       timeout_s: float = COMMAND_TIMEOUT_S) -> T:
        try:
            async with asyncio.timeout(timeout_s):
                return await call()
        except TimeoutError:
            raise CommandRefused(command, "TIMEOUT", vehicle=self._name, retryable=True,
                                 detail=f"no answer within {timeout_s:g} s") from None
        except MissionRawError as exc:
            raise MissionUploadError(f"{command}: {exc.result.name}", vehicle=self._name) from None
        except (ActionError, OffboardError, TelemetryError) as exc:
            name = exc.result.name
            raise CommandRefused(command, name, vehicle=self._name, retryable=name in _RETRYABLE) from None
        except MavsdkError as exc:
            raise CommandRefused(command, type(exc).__name__, vehicle=self._name, retryable=False,
                                 detail=str(exc)) from None

    async def get_param(self, name: str) -> float | None:
        return await self._params.get(name)

    async def set_param(self, name: str, value: float) -> None:
        await self._params.set(name, value)

    async def set_mode(self, mode: FlightMode, what: str = "set mode") -> None:
        calls = {FlightMode.HOLD: self._action.hold, FlightMode.RETURN_TO_LAUNCH: self._action.return_to_launch,
                 FlightMode.LAND: self._action.land}
        if mode is FlightMode.OFFBOARD:
            await self._command(what, self._offboard.start)
            return
        if mode not in calls:
            raise CommandRefused(what, "UNSUPPORTED", vehicle=self._name, detail=f"no MAVSDK call for {mode.value}")
        await self._command(what, calls[mode])

    async def upload_route(self, waypoints: Sequence[GeoWaypoint], acceptance_radius_m: float) -> None:
        if not waypoints:
            raise MissionUploadError("empty route", vehicle=self._name)
        items = waypoints_to_items(waypoints, acceptance_radius_m)
        await self._command("mission upload", lambda: self._mission.upload_mission(items),
                            MISSION_TRANSFER_TIMEOUT_S)

    async def download_route(self) -> tuple[GeoWaypoint, ...]:
        items = await self._command("mission download", self._mission.download_mission,
                                    MISSION_TRANSFER_TIMEOUT_S)
        return items_to_waypoints(items)

    async def upload_fence(self, zones: Sequence[GeoFenceZone]) -> None:
        items = [MissionItem(seq=i, frame=MAV_FRAME_GLOBAL, command=it.command, current=0, autocontinue=1,
                             param1=it.param1, param2=0.0, param3=0.0, param4=0.0, x=it.lat_e7, y=it.lon_e7, z=0.0,
                             mission_type=MAV_MISSION_TYPE_FENCE) for i, it in enumerate(fence_items(zones))]
        await self._command("geofence upload", lambda: self._mission.upload_geofence(items), MISSION_TRANSFER_TIMEOUT_S)

    async def download_fence(self) -> tuple[GeoFenceZone, ...]:
        items = await self._command("geofence download", self._mission.download_geofence, MISSION_TRANSFER_TIMEOUT_S)
        return fence_zones([FenceItem(int(it.command), float(it.param1), int(it.x), int(it.y)) for it in items])

    async def arm(self) -> None:
        await self._command("arm", self._action.arm)

    async def disarm(self) -> None:
        await self._command("disarm", self._action.disarm)

    async def takeoff(self, alt_rel_m: float) -> None:
        # PX4 takes off to MIS_TAKEOFF_ALT; MAVSDK sets it through the param protocol. Skipped when
        # it was set already (before arming): COM_DISARM_PRFLT counts from the arm to the take-off.
        if self._params.known("MIS_TAKEOFF_ALT") != float(alt_rel_m):
            await self._command("set takeoff altitude", lambda: self._action.set_takeoff_altitude(float(alt_rel_m)))
        await self._command("takeoff", self._action.takeoff)

    async def start_offboard(self, first: VelocityYawRateSetpoint) -> None:
        # PX4 refuses OFFBOARD unless setpoints are already flowing: send one first.
        await self.send_setpoint(first)
        await self._command("offboard start", self._offboard.start)

    async def send_setpoint(self, setpoint: VelocityYawRateSetpoint) -> None:
        body = body_setpoint(setpoint)
        await self._command("offboard setpoint", lambda: self._offboard.set_velocity_body(body))

    async def hold(self) -> None:
        if self._board.status().mode is FlightMode.OFFBOARD:
            # offboard.stop() switches to HOLD and ends MAVSDK's own 20 Hz setpoint resend.
            try:
                await self._command("offboard stop", self._offboard.stop)
                return
            except CommandRefused:
                pass
        await self._command("hold", self._action.hold)

    async def land(self) -> None:
        await self._command("land", self._action.land)

    # -- pumps ----------------------------------------------------------------------------
    async def _limit_stream_rates(self) -> None:
        """Ask for the pumped streams at ``telemetry_hz``, again while the answer may change; an autopilot
        that refuses keeps its own rates. Runs beside the pumps: a slow answer delays nothing."""
        t, rate_hz = self._telemetry, self._telemetry_hz
        for what, call in (("attitude", t.set_rate_attitude_euler), ("position", t.set_rate_position),
                           ("velocity", t.set_rate_velocity_ned)):
            for attempt in range(1, STREAM_RATE_ATTEMPTS + 1):
                try:
                    await self._command(f"set {what} rate", lambda: call(rate_hz))
                    log.info("vehicle %s: %s at %g Hz (attempt %d)", self._name, what, rate_hz, attempt)
                    break
                except CommandRefused as exc:
                    if not exc.retryable or attempt == STREAM_RATE_ATTEMPTS:
                        log.warning("%s after %d attempt(s) (keeping the autopilot's own rate)", exc, attempt)
                        break
                await asyncio.sleep(STREAM_RATE_RETRY_S)

    def _stream(self, gen: AsyncGenerator[T, None]) -> AsyncGenerator[T, None]:
        self._streams.append(gen)
        return gen

    async def close_streams(self) -> None:
        """Unsubscribe while MAVSDK runs: a pump cancelled in its loop body leaves its stream open,
        and closing it after ``destroy`` (at the loop's shutdown) blocks in the C library."""
        for gen in self._streams:
            await gen.aclose()
        self._streams.clear()

    def start_pumps(self, tg: asyncio.TaskGroup) -> list[asyncio.Task]:
        pumps = (self._limit_stream_rates, self._pump_attitude, self._pump_position, self._pump_velocity,
                 self._pump_mode, self._pump_armed, self._pump_landed, self._pump_health, self._pump_battery,
                 self._pump_traffic, self._pump_text, self._pump_gps, self._pump_home, self._pump_link_guard)
        return [tg.create_task(p(), name=f"{self._name}:{p.__name__}") for p in pumps]

    async def _maybe_emit(self) -> None:
        if not (self._att_fresh and self._pos_fresh) or self._att is None or self._pos is None:
            return
        self._att_fresh = self._pos_fresh = False
        t_sim, heading = self._att
        x, y, alt = self._pos
        await self._board.put_pose(t_sim_s=t_sim, x_east_m=x, y_north_m=y, alt_rel_m=alt,
                                   vx_east_m_s=self._vel[0], vy_north_m_s=self._vel[1],
                                   heading_enu_rad=heading)

    async def _pump_attitude(self) -> None:
        async for a in self._stream(self._telemetry.subscribe_attitude_euler()):
            t_sim = a.timestamp_us / 1e6
            await self._board.note_clock(t_sim)
            self._att = (t_sim, frames.ned_yaw_to_enu_heading(math.radians(a.yaw_deg)))
            self._att_fresh = True
            await self._maybe_emit()

    async def _pump_position(self) -> None:
        async for p in self._stream(self._telemetry.subscribe_position()):
            if not (math.isfinite(p.latitude_deg) and math.isfinite(p.longitude_deg)):
                continue
            x, y, _ = frames.geodetic_to_local(self._origin, p.latitude_deg, p.longitude_deg)
            self._pos = (x, y, float(p.relative_altitude_m))
            self._pos_fresh = True
            stamps = None if self._guard is None else self._guard.stamps
            stamp = None if stamps is None else stamps.lookup(p.latitude_deg, p.longitude_deg, p.relative_altitude_m)
            if stamp is not None and self._att is not None:  # the position's own time (position_stamps)
                self._att, self._att_fresh = (stamp, self._att[1]), True
            elif stamps is not None and stamps.matched:
                self._pos_fresh = False  # stamped before but not this one: no time to trust, so no sample
            await self._maybe_emit()

    async def _pump_velocity(self) -> None:
        async for v in self._stream(self._telemetry.subscribe_velocity_ned()):
            east, north, _ = frames.ned_to_enu(v.north_m_s, v.east_m_s, v.down_m_s)
            self._vel = (east, north)

    async def _pump_mode(self) -> None:
        async for m in self._stream(self._telemetry.subscribe_flight_mode()):
            await self._board.put_status(mode=_MODES.get(m, FlightMode.OTHER))

    async def _pump_armed(self) -> None:
        async for armed in self._stream(self._telemetry.subscribe_armed()):
            await self._board.put_status(armed=bool(armed))

    async def _pump_landed(self) -> None:
        async for s in self._stream(self._telemetry.subscribe_landed_state()):
            await self._board.put_status(landed=_LANDED.get(s, LandedState.UNKNOWN))

    async def _pump_health(self) -> None:
        async for ok in self._stream(self._telemetry.subscribe_health_all_ok()):
            await self._board.put_status(health_ok=bool(ok))

    async def _pump_text(self) -> None:
        async for t in self._stream(self._telemetry.subscribe_status_text()):
            await self._board.put_text(str(t.text))

    async def _pump_gps(self) -> None:
        async for g in self._stream(self._telemetry.subscribe_gps_info()):
            await self._board.put_status(gps_fix_type=int(g.fix_type))

    async def _pump_home(self) -> None:
        async for h in self._stream(self._telemetry.subscribe_health()):
            await self._board.put_status(home_ok=bool(h.is_home_position_ok))

    def link_events(self) -> dict[str, int]:
        return {} if self._guard is None else self._guard.link_events()

    async def _pump_link_guard(self) -> None:
        if self._guard is not None:
            await self._guard.conflicted.wait()
            await self._board.put_status(link_conflict=self._guard.conflict)

    async def _pump_battery(self) -> None:
        async for b in self._stream(self._telemetry.subscribe_battery()):
            pct = float(b.remaining_percent)
            await self._board.put_status(battery_pct=pct if math.isfinite(pct) else None)

    async def _pump_traffic(self) -> None:
        async for a in self._stream(self._transponder.subscribe_transponder()):
            callsign = str(a.callsign).strip().strip("\x00")
            if not callsign or not (math.isfinite(a.latitude_deg) and math.isfinite(a.longitude_deg)):
                continue
            x, y, _ = frames.geodetic_to_local(self._origin, a.latitude_deg, a.longitude_deg)
            vx, vy = traffic_velocity_enu(float(a.heading_deg), float(a.horizontal_velocity_m_s))
            # The vehicle's clock when it sent the report (position_stamps), else the newest we have.
            t_sim = None if self._guard is None else self._guard.stamps.lookup_traffic(
                a.icao_address, a.latitude_deg, a.longitude_deg)
            if t_sim is None:
                t_sim = self._board.latest_clock_s if self._board.latest_clock_s is not None else math.nan
            await self._board.put_traffic(TrafficReport(
                callsign=callsign, x_east_m=x, y_north_m=y,
                vx_east_m_s=vx, vy_north_m_s=vy,
                t_sim_s=t_sim, t_wall_s=time.monotonic(), via=self._name))
