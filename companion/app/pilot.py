"""One vehicle's flight, from route upload to landing, driven by its own telemetry in sim time.

    upload + verify -> (all vehicles) -> arm, take off -> (all vehicles airborne) -> OFFBOARD:
    one planner tick per dt of the vehicle's sim clock -> at the station: hold, land

The control loop is event-driven: it waits for the next position sample (with a wall-clock bound
scaled by the measured speed factor), and ticks the shared :class:`VehiclePlanner` whenever the
vehicle's clock has passed the next tick time. Between ticks a keep-alive task resends the
current setpoint so that the autopilot's offboard-loss timer (sim time) never runs out at high
speed factors or on a lossy link. It never sends a setpoint computed from stale data: when
telemetry stops, the setpoint becomes a hover until it is fresh again, and a link that stays
silent ends the flight as ``link_lost``.

Every way out of :meth:`Pilot.fly` that is not a landing at the station leaves the vehicle safe:
holding in the air (offboard stopped), or disarmed on the ground.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from uav_model import frames
from companion.app import monitors
from companion.app.flight_log import FlightLog
from companion.app.flight_plan import FlightPlan, verify_readback
from companion.errors import (CommandRefused, CompanionError, MissionAborted, MissionUploadError, TelemetryLost,
                              primary_error)
from uav_model.mission import VehicleSpec
from companion.planning.dwa import OtherUav, Pose, inflated_clearance
from companion.planning.fleet import Neighbour, choose_other
from companion.planning.obstacle_field import ObstacleField, ObstacleTrack
from companion.planning.routes import higher_routes
from companion.planning.vehicle_planner import TickResult, VehiclePlanner
from companion.vehicle.port import (HOVER, FlightMode, LandedState, PoseSample, TrafficReport, Vehicle,
                                    VelocityYawRateSetpoint)


@dataclass(frozen=True)
class RunSettings:
    """How the runner flies; every duration says whether it is sim or wall time."""

    shared_clock: bool = True  # all vehicles stamp with one sim clock (the embedded stub)
    connect_timeout_s: float = 15.0  # wall
    ready_timeout_s: float = 30.0  # wall
    command_attempts: int = 3
    progress_every_s: float = 20.0  # sim
    lookahead_s: float = 2.0  # sim, safety monitors
    link_lost_after_s: float = 10.0  # sim, continuous silence before the flight is abandoned
    keepalive_sim_s: float = 0.1  # sim, setpoint resend period (bounded to 10..100 ms wall)
    max_offboard_reentries: int = 10
    land: bool = True
    safe_state_timeout_s: float = 5.0  # wall


@dataclass
class PilotOutcome:
    """What happened to one vehicle (mutable while it flies; read when it is done)."""

    name: str
    phase: str = "connected"  # connected, uploaded, arming, armed, takeoff, airborne, offboard, arrived, landed, held, ...
    t_depart_sim_s: float | None = None
    arrival_t_mission_s: float | None = None
    landed: bool = False
    planner_ms: list[float] = field(default_factory=list)
    interventions: Counter = field(default_factory=Counter)  # why a tick hovered instead
    offboard_reentries: int = 0
    ticks: int = 0
    error: str | None = None


class FlightContext:
    """What the pilots share: the plan, the settings, the log, the fleet, one barrier."""

    def __init__(self, plan: FlightPlan, settings: RunSettings, log: FlightLog,
                 vehicles: Mapping[str, Vehicle], report: Callable[[str], None]):
        self.plan = plan
        self.mission = plan.mission
        self.settings = settings
        self.log = log
        self.vehicles = dict(vehicles)
        self.report = report
        self.field = ObstacleField.from_world(plan.mission.world)
        self.barrier = asyncio.Barrier(len(self.vehicles))
        self.arrived: set[str] = set()  # vehicles parked at their station: others drop the sightline term
        self.rank = {v.name: i for i, v in enumerate(plan.mission.by_priority)}
        # ADS-B callsigns hold 8 characters: match them to the mission's moving obstacles.
        moving = [o.id for o in plan.mission.world.moving_obstacles]
        self._callsigns = {oid[:8]: oid for oid in moving}
        self._callsigns.update({oid: oid for oid in moving})

    def obstacle_id(self, callsign: str) -> str:
        """The mission obstacle an ADS-B callsign stands for (unknown ones keep their callsign)."""
        return self._callsigns.get(callsign, callsign)

    def track_time(self, pilot: "Pilot", t_sim_s: float) -> float:
        """The time base of the flown tracks: the shared sim clock (which also drives the moving
        obstacles' truth), or per-vehicle mission time when the vehicles' clocks are unrelated."""
        if self.settings.shared_clock:
            return t_sim_s
        return t_sim_s - (pilot.outcome.t_depart_sim_s or 0.0)


def wall_for_sim(vehicle: Vehicle, sim_s: float, slack_s: float = 5.0) -> float:
    """A wall-clock bound for something that takes ``sim_s`` of the vehicle's sim time."""
    rate = vehicle.sim_rate()
    rate = rate if rate is not None and rate > 0.05 else 1.0
    return sim_s / rate + slack_s


class Pilot:
    def __init__(self, ctx: FlightContext, spec: VehicleSpec):
        self.ctx = ctx
        self.spec = spec
        self.name = spec.name
        self.vehicle = ctx.vehicles[spec.name]
        self.planner = VehiclePlanner.build(ctx.mission, spec, ctx.plan.routes.get(spec.name), ctx.plan.variant,
                                            earlier=higher_routes(ctx.mission, ctx.plan.routes, spec.name))
        self.outcome = PilotOutcome(spec.name)
        self.setpoint: VelocityYawRateSetpoint = HOVER
        self._offboard_live = False  # the keep-alive resends only while this is set
        self._next_progress_s = 0.0
        self._snapshot = ctx.field.from_tracks(())  # the obstacles as last seen by a tick

    # -- the whole flight ------------------------------------------------------------------
    async def fly(self) -> PilotOutcome:
        try:
            await self.vehicle.wait_ready(self.ctx.settings.ready_timeout_s)
            await self.upload_and_verify()
            self.outcome.phase = "uploaded"
            await self._barrier("all routes uploaded", self.ctx.settings.ready_timeout_s)
            await self._take_off()
            await self._barrier("all vehicles airborne", wall_for_sim(self.vehicle, self._climb_sim_s(), 30.0))
            await self._fly_offboard()
            await self._finish()
            return self.outcome
        except BaseException as exc:
            self.outcome.error = self.outcome.error or (str(exc) or type(exc).__name__)
            await self._make_safe()
            raise

    async def _barrier(self, what: str, timeout_s: float) -> None:
        try:
            async with asyncio.timeout(timeout_s):
                await self.ctx.barrier.wait()
        except TimeoutError:
            raise MissionAborted("timeout", f"gave up waiting {timeout_s:.0f} s for {what}", vehicle=self.name) from None
        except asyncio.BrokenBarrierError:
            raise MissionAborted("aborted", f"another vehicle failed before {what}", vehicle=self.name) from None

    async def _retry(self, what: str, call: Callable[[], object]):
        """Call with retries on answers that may change (busy, timeout); refusals are final."""
        attempts = self.ctx.settings.command_attempts
        for attempt in range(1, attempts + 1):
            try:
                return await call()
            except (CommandRefused, MissionUploadError) as exc:
                retryable = isinstance(exc, MissionUploadError) or exc.retryable
                if not retryable or attempt == attempts:
                    raise
                self.ctx.report(f"{self.name}: {what} failed ({exc.message}), retry {attempt}/{attempts - 1}")
                await asyncio.sleep(0.5 * attempt)

    # -- phases ----------------------------------------------------------------------------
    async def upload_and_verify(self) -> None:
        waypoints = self.ctx.plan.waypoints(self.spec)
        radius = self.ctx.mission.planner.acceptance_radius_m
        await self._retry("mission upload", lambda: self.vehicle.upload_route(waypoints, radius))
        got = await self._retry("mission download", self.vehicle.download_route)
        verify_readback(self.name, waypoints, got)
        self.ctx.report(f"{self.name}: route uploaded and read back ({len(waypoints)} waypoints)")

    def _climb_sim_s(self) -> float:
        return self.spec.cruise_alt_m / 0.5 + 30.0  # PX4 climbs at >= 0.5 m/s (MPC_TKO_SPEED)

    async def _take_off(self) -> None:
        self.outcome.phase = "arming"  # from here on the vehicle may be armed, even if we are cancelled
        await self._retry("arm", self.vehicle.arm)
        self.outcome.phase = "armed"
        # Nobody leaves the ground unless everybody could arm: a refusal then only disarms.
        await self._barrier("all vehicles armed", self.ctx.settings.ready_timeout_s)
        alt = self.spec.cruise_alt_m
        await self._retry("takeoff", lambda: self.vehicle.takeoff(alt))
        self.outcome.phase = "takeoff"
        target = alt - 1.0  # PX4 ends TAKEOFF within a few decimetres of MIS_TAKEOFF_ALT
        await self.vehicle.wait_until(lambda s, p: p is not None and p.alt_rel_m >= target,
                                      wall_for_sim(self.vehicle, self._climb_sim_s()), f"take-off to {alt:g} m")
        self.outcome.phase = "airborne"
        self.ctx.report(f"{self.name}: airborne at {alt:g} m")

    async def _fly_offboard(self) -> None:
        pose = await self.vehicle.next_pose(0, wall_for_sim(self.vehicle, 2.0))
        result = self._tick(pose)
        self.setpoint = self._setpoint(pose, result)[0]
        # Setpoints stream (keep-alive) from before the mode switch to the end, as PX4 requires.
        self._offboard_live = True
        try:
            async with asyncio.TaskGroup() as tg:
                keepalive = tg.create_task(self._keepalive(), name=f"{self.name}:keepalive")
                control = tg.create_task(self._engage_and_fly(), name=f"{self.name}:control")
                control.add_done_callback(lambda _: keepalive.cancel())
        except BaseExceptionGroup as group:
            raise primary_error(group) from None
        finally:
            self._offboard_live = False

    async def _engage_and_fly(self) -> None:
        await self.vehicle.send_setpoint(self.setpoint)
        # Mission time starts when the companion asks for control (the headless runner's t = 0):
        # the OFFBOARD heartbeat arrives a link latency after the vehicle has started to move.
        depart = self.vehicle.latest_pose()
        assert depart is not None
        await self._retry("offboard start", lambda: self.vehicle.start_offboard(self.setpoint))
        await self.vehicle.wait_until(lambda s, p: s.mode is FlightMode.OFFBOARD,
                                      wall_for_sim(self.vehicle, 5.0), "OFFBOARD mode")
        self.outcome.phase = "offboard"
        self.outcome.t_depart_sim_s = depart.t_sim_s
        self._record(depart)
        pose = self.vehicle.latest_pose()
        assert pose is not None
        self._record(pose)
        self.ctx.report(f"{self.name}: OFFBOARD, departed at t_sim={depart.t_sim_s:.1f} s")
        await self._control_loop(pose)

    async def _keepalive(self) -> None:
        while True:
            rate = self.vehicle.sim_rate() or 1.0
            period = min(0.1, max(0.01, self.ctx.settings.keepalive_sim_s / rate))
            await asyncio.sleep(period)
            if self._offboard_live:
                try:
                    await self.vehicle.send_setpoint(self.setpoint)
                except CommandRefused:
                    pass  # the next tick or resend tries again; a dead link is the control loop's call

    async def _control_loop(self, pose: PoseSample) -> None:
        dt = self.ctx.mission.planner.dt_s
        timeout = self.ctx.mission.safety.telemetry_timeout_s
        next_tick = pose.t_sim_s + dt
        stale_since: float | None = None
        seq = pose.seq
        while True:
            bound = monitors.wall_bound_s(timeout, self.vehicle.sim_rate())
            watch_clock = stale_since is None  # once stale, only a new sample ends it

            def news(st, p) -> bool:
                return p is not None and (p.seq > seq or (
                    watch_clock and monitors.is_stale(p.t_sim_s, self.vehicle.clock_s(), timeout)))
            try:
                await self.vehicle.wait_until(news, bound, "fresh position")
                fresh = self.vehicle.latest_pose()
                assert fresh is not None
                if fresh.seq == seq:
                    raise TelemetryLost("position stopped while the clock ran on", vehicle=self.name)
                seq = fresh.seq
                if monitors.is_stale(fresh.t_sim_s, self.vehicle.clock_s(), timeout):
                    raise TelemetryLost("position lags the vehicle clock", vehicle=self.name)
            except TelemetryLost as exc:
                first = stale_since is None
                stale_since = time.monotonic() if stale_since is None else stale_since
                await self._on_stale(exc, first, time.monotonic() - stale_since)
                continue
            if stale_since is not None:
                self.ctx.report(f"{self.name}: telemetry fresh again after {time.monotonic() - stale_since:.2f} s wall")
                stale_since = None
            pose = fresh
            self._record(pose)
            await self._check_mode()
            if pose.t_sim_s + 1e-6 < next_tick and not self._at_station(pose):
                continue  # arrival is checked on every sample: a tick-only check can step past the radius
            next_tick += dt
            if next_tick <= pose.t_sim_s:  # samples came late: skip the ticks we missed
                next_tick = pose.t_sim_s + dt
            t_mission = pose.t_sim_s - (self.outcome.t_depart_sim_s or pose.t_sim_s)
            if t_mission > self.ctx.mission.safety.time_limit_s:
                raise MissionAborted("timeout", f"time limit {self.ctx.mission.safety.time_limit_s:g} s reached",
                                     vehicle=self.name)
            result = self._tick(pose)
            if result.arrived:
                self.outcome.arrival_t_mission_s = t_mission
                self.outcome.phase = "arrived"
                self.ctx.arrived.add(self.name)
                self.ctx.report(f"{self.name}: arrived at {self.spec.goal} after {t_mission:.1f} s")
                return
            setpoint, action = self._setpoint(pose, result)
            self.setpoint = setpoint
            try:
                await self.vehicle.send_setpoint(setpoint)
            except CommandRefused as exc:  # the keep-alive resends it; a dead link shows as stale telemetry
                self.outcome.interventions[f"setpoint not sent: {exc.result}"] += 1
            self._log_tick(pose, t_mission, result, setpoint, action)
            if self.planner.replan_due:
                await self._replan(pose, t_mission)

    async def _replan(self, pose: PoseSample, t_mission: float) -> None:
        """No progress for a while: plan a new route from here in a worker thread (A* must not
        stall the other vehicle's loop), flying the setpoint just sent meanwhile."""
        x, y = pose.x_east_m, pose.y_north_m
        if getattr(self.vehicle, "clock_follows_event_loop", False):  # in-process: inline costs no sim time
            nodes = self.planner.plan_detour(x, y)
        else:
            nodes = await asyncio.to_thread(self.planner.plan_detour, x, y)
        if self.planner.adopt_detour(nodes, x, y, t_mission):
            self.outcome.interventions["planner: re-planned"] += 1
            self.ctx.report(f"{self.name}: no progress for {self.planner.replanning.after_s:g} s: "
                            f"new route from ({x:.0f}, {y:.0f}), {len(nodes)} nodes")
        else:
            self.outcome.interventions["planner: no new route"] += 1

    async def _on_stale(self, exc: TelemetryLost, first: bool, stale_wall_s: float) -> None:
        """Never fly on old data: hover, and give up when the silence lasts too long."""
        s = self.ctx.settings
        self.setpoint = HOVER
        self.outcome.interventions["stale"] += 1
        try:
            await self.vehicle.send_setpoint(HOVER)
        except CommandRefused:
            pass
        if first:
            self.ctx.report(f"{self.name}: telemetry stale ({exc.message}); hovering")
            self.ctx.log.row(t_sim_s=self.vehicle.clock_s(), vehicle=self.name, phase="offboard",
                             action="hover", note=f"stale: {exc.message}")
        limit_wall = wall_for_sim(self.vehicle, s.link_lost_after_s, slack_s=1.0)
        if stale_wall_s > limit_wall:
            raise MissionAborted("link_lost", f"no fresh telemetry for {stale_wall_s:.1f} s wall", vehicle=self.name)

    async def _check_mode(self) -> None:
        mode = self.vehicle.status().mode
        if mode is FlightMode.OFFBOARD:
            return
        if mode is FlightMode.HOLD and self.outcome.offboard_reentries < self.ctx.settings.max_offboard_reentries:
            # The autopilot's offboard-loss failsafe: setpoints were late. Resume, visibly.
            self.outcome.offboard_reentries += 1
            self.ctx.report(f"{self.name}: autopilot fell back to HOLD (offboard loss); re-entering OFFBOARD "
                            f"({self.outcome.offboard_reentries}/{self.ctx.settings.max_offboard_reentries})")
            await self._retry("offboard start", lambda: self.vehicle.start_offboard(self.setpoint))
            await self.vehicle.wait_until(lambda st, p: st.mode is FlightMode.OFFBOARD,
                                          wall_for_sim(self.vehicle, 5.0), "OFFBOARD mode")
            return
        if mode is FlightMode.HOLD:
            raise MissionAborted("link_lost", "offboard lost too often; left in HOLD", vehicle=self.name)
        # Someone else (a pilot, a failsafe) chose another mode: stop commanding, do not fight it.
        self.outcome.phase = "override"
        raise MissionAborted("override", f"mode changed to {mode.value} by someone else; companion stands down",
                             vehicle=self.name)

    async def _finish(self) -> None:
        """Hold at the station, then land. The flight has succeeded by now (SPEC §2 asks for the
        arrival): a refused landing is reported, and leaves the vehicle holding, not a failure."""
        try:
            await self._hold_and_land()
        except CompanionError as exc:
            self.outcome.error = str(exc)
            self.ctx.report(f"{self.name}: after arrival: {exc}; left in {self.vehicle.status().mode.value}")

    async def _hold_and_land(self) -> None:
        await self._retry("hold", self.vehicle.hold)
        await self.vehicle.wait_until(lambda s, p: s.mode is FlightMode.HOLD, wall_for_sim(self.vehicle, 5.0), "HOLD")
        self.outcome.phase = "held"
        if not self.ctx.settings.land:
            return
        await self._retry("land", self.vehicle.land)
        self.outcome.phase = "landing"
        await self.vehicle.wait_until(lambda s, p: s.landed is LandedState.ON_GROUND,
                                      wall_for_sim(self.vehicle, self.spec.cruise_alt_m / 0.3 + 30.0), "landing")
        self.outcome.phase = "landed"
        self.outcome.landed = True
        self.ctx.report(f"{self.name}: landed at {self.spec.goal}")

    async def _make_safe(self) -> None:
        """Leave the vehicle safe after a failure or interruption, within a wall bound."""
        self._offboard_live = False
        phase = self.outcome.phase
        try:
            async with asyncio.timeout(self.ctx.settings.safe_state_timeout_s):
                if phase in ("takeoff", "airborne", "offboard", "arrived"):
                    await self.vehicle.hold()
                    self.outcome.phase = "held"
                    self.ctx.report(f"{self.name}: holding position (offboard stopped)")
                elif phase in ("arming", "armed"):  # disarming a disarmed vehicle is a no-op
                    await self.vehicle.disarm()
                    self.outcome.phase = "disarmed"
        except (TimeoutError, CompanionError) as exc:
            self.ctx.report(f"{self.name}: could not make safe from phase {phase!r}: {exc or 'timeout'}; "
                            "the autopilot's own failsafe applies")

    # -- one tick ----------------------------------------------------------------------------
    def _at_station(self, pose: PoseSample) -> bool:
        sx, sy = self.planner.station_xy
        return math.hypot(pose.x_east_m - sx, pose.y_north_m - sy) <= self.planner.arrival_radius_m

    def _tick(self, pose: PoseSample) -> TickResult:
        t_mission = pose.t_sim_s - (self.outcome.t_depart_sim_s or pose.t_sim_s)
        own = Pose(pose.x_east_m, pose.y_north_m, pose.heading_enu_rad)
        self._snapshot = self.ctx.field.from_tracks(self._obstacle_tracks(pose))
        result = self.planner.tick(own, self._other(pose), self._snapshot, t_mission)
        self.outcome.ticks += 1
        if not result.arrived:
            self.outcome.planner_ms.append(result.planner_ms)
        return result

    def _age_s(self, at: PoseSample, t_sim_s: float, t_wall_s: float, same_link: bool) -> float:
        """How old (sim seconds) a report stamped (t_sim, t_wall) is at the pose ``at``."""
        if same_link or self.ctx.settings.shared_clock:
            age = at.t_sim_s - t_sim_s
        else:
            age = (at.t_wall_s - t_wall_s) * (self.vehicle.sim_rate() or 1.0)
        return min(max(age, 0.0), 5.0) if math.isfinite(age) else 0.0

    def _other(self, pose: PoseSample) -> OtherUav | None:
        """The vehicle the planner reacts to (fleet.choose_other: separation first, then priority)."""
        chosen = choose_other(pose.x_east_m, pose.y_north_m, self.ctx.rank[self.name], self._neighbours(pose),
                              self.planner.config)
        return None if chosen is None else chosen.uav

    def _nearest_other(self, pose: PoseSample) -> tuple[str | None, OtherUav | None]:
        """The nearest other vehicle, from its own telemetry, extrapolated to this pose's time."""
        nearest = min(self._neighbours(pose), default=None,
                      key=lambda n: math.hypot(n.uav.x_m - pose.x_east_m, n.uav.y_m - pose.y_north_m))
        return (None, None) if nearest is None else (nearest.name, nearest.uav)

    def _neighbours(self, pose: PoseSample) -> list[Neighbour]:
        """Every other vehicle with telemetry, extrapolated to this pose's time."""
        out = []
        for name, v in self.ctx.vehicles.items():
            p = v.latest_pose() if name != self.name else None
            if p is None:
                continue
            age = self._age_s(pose, p.t_sim_s, p.t_wall_s, same_link=False)
            x, y = p.x_east_m + p.vx_east_m_s * age, p.y_north_m + p.vy_north_m_s * age
            out.append(Neighbour(name, self.ctx.rank[name],
                                 OtherUav(x, y, p.vx_east_m_s, p.vy_north_m_s, arrived=name in self.ctx.arrived)))
        return out

    def _traffic(self) -> dict[str, TrafficReport]:
        """Each moving obstacle's latest report, preferring this vehicle's own link."""
        merged: dict[str, TrafficReport] = {}
        for v in self.ctx.vehicles.values():
            for callsign, r in v.traffic().items():
                cur = merged.get(callsign)
                if cur is None or (cur.via != self.name and (r.via == self.name or r.t_wall_s > cur.t_wall_s)):
                    merged[callsign] = r
        return merged

    def _obstacle_tracks(self, pose: PoseSample) -> list[ObstacleTrack]:
        tracks = []
        for callsign, r in self._traffic().items():
            self.ctx.log.traffic(r.t_sim_s, callsign, r.via, r.x_east_m, r.y_north_m, r.vx_east_m_s, r.vy_north_m_s)
            age = self._age_s(pose, r.t_sim_s, r.t_wall_s, same_link=r.via == self.name)
            tracks.append(ObstacleTrack(self.ctx.obstacle_id(callsign), r.x_east_m + r.vx_east_m_s * age,
                                        r.y_north_m + r.vy_north_m_s * age, r.vx_east_m_s, r.vy_north_m_s))
        return tracks

    def _setpoint(self, pose: PoseSample, result: TickResult) -> tuple[VelocityYawRateSetpoint, str]:
        if result.command is None:
            reason = result.hold_reason or "no command"
            self.outcome.interventions[f"planner: {reason}"] += 1
            return HOVER, f"hover ({reason})"
        v, w = result.speed_m_s, result.yaw_rate_rad_s
        s = self.ctx.settings
        dt = self.ctx.mission.planner.dt_s
        own = monitors.Kinematic2D(pose.x_east_m, pose.y_north_m, pose.heading_enu_rad,
                                   pose.vx_east_m_s, pose.vy_north_m_s)
        other_name, other = self._nearest_other(pose)
        other_k = None if other is None else monitors.Kinematic2D(other.x_m, other.y_m, 0.0, other.vx_m_s, other.vy_m_s)
        priority = other_name is None or self.ctx.rank[self.name] < self.ctx.rank[other_name]
        for verdict in (
            monitors.check_separation(own, v, w, other_k, min_separation_m=self.ctx.mission.safety.min_separation_m,
                                      own_has_priority=priority,
                                      horizon_s=s.lookahead_s, step_s=dt / 2),
            monitors.check_geofence(self.ctx.mission.world, own, v, w, horizon_s=s.lookahead_s, step_s=dt / 2),
        ):
            if verdict.hover:
                self.outcome.interventions[verdict.reason] += 1
                if verdict.reason == "geofence":
                    return self._turn_in(pose, dt), "turn in place (geofence monitor)"
                return HOVER, f"hover ({verdict.reason} monitor)"
        # The planner is planar; hold the cruise altitude with a gentle proportional climb rate.
        climb = max(-1.0, min(1.0, 0.5 * (self.spec.cruise_alt_m - pose.alt_rel_m)))
        action = "fly"
        if result.recovery_reason is not None:  # speed 0 + yaw rate: the autopilot yaws in place
            self.outcome.interventions["planner: spin recovery"] += 1
            action = "recover (yaw in place)"
        return VelocityYawRateSetpoint(forward_m_s=v, yaw_rate_enu_rad_s=w, climb_m_s=climb), action

    def _turn_in(self, pose: PoseSample, dt: float) -> VelocityYawRateSetpoint:
        """Stop and yaw toward the middle of the area. The monitor looks closer than the planner
        (half its step), so near the fence it can veto a command the planner found legal; a plain
        hover keeps the heading, and the planner would ask for the same command for ever."""
        w = self.ctx.mission.world
        cx, cy = (w.x_min_m + w.x_max_m) / 2.0, (w.y_min_m + w.y_max_m) / 2.0
        error = frames.wrap_pi(math.atan2(cy - pose.y_north_m, cx - pose.x_east_m) - pose.heading_enu_rad)
        rate = self.spec.max_yaw_rate_rad_s
        return VelocityYawRateSetpoint(forward_m_s=0.0, yaw_rate_enu_rad_s=max(-rate, min(rate, error / dt)))

    # -- logging ----------------------------------------------------------------------------
    def _record(self, pose: PoseSample) -> None:
        self.ctx.log.track(self.name).add(self.ctx.track_time(self, pose.t_sim_s), pose.x_east_m, pose.y_north_m)

    def _remaining_m(self, pose: PoseSample) -> float:
        nodes = self.planner.tracker.nodes
        i = self.planner.tracker.index
        rest = float(np.sum(np.hypot(*np.diff(nodes[i:], axis=0).T))) if i < len(nodes) - 1 else 0.0
        return math.hypot(nodes[i][0] - pose.x_east_m, nodes[i][1] - pose.y_north_m) + rest

    def _log_tick(self, pose: PoseSample, t_mission: float, result: TickResult,
                  setpoint: VelocityYawRateSetpoint, action: str) -> None:
        clearance = inflated_clearance(np.array([pose.x_east_m]), np.array([pose.y_north_m]), np.zeros(1),
                                       self._snapshot)
        clear_m = float(clearance.min()) if clearance.size else math.inf
        other = self._other(pose)
        sep_m = math.inf if other is None else math.hypot(other.x_m - pose.x_east_m, other.y_m - pose.y_north_m)
        to_go = self._remaining_m(pose)
        mode = self.vehicle.status().mode.value
        self.ctx.log.row(t_mission_s=t_mission, t_sim_s=pose.t_sim_s, vehicle=self.name, phase=self.outcome.phase,
                         mode=mode, x_m=pose.x_east_m, y_m=pose.y_north_m, alt_m=pose.alt_rel_m,
                         heading_deg=math.degrees(pose.heading_enu_rad), speed_m_s=pose.ground_speed_m_s,
                         cmd_forward_m_s=setpoint.forward_m_s, cmd_yaw_rate_deg_s=math.degrees(setpoint.yaw_rate_enu_rad_s),
                         action=action, goal_index=result.goal_index, dist_to_goal_m=to_go, clearance_m=clear_m,
                         separation_m=sep_m, planner_ms=result.planner_ms)
        if t_mission >= self._next_progress_s:
            self._next_progress_s = t_mission + self.ctx.settings.progress_every_s
            self.ctx.report(f"t={t_mission:7.1f} s  {self.name:>3} {mode:<8} to go {to_go:7.0f} m  "
                            f"clearance {clear_m:6.0f} m  separation {sep_m:6.0f} m  {action}")
