"""One vehicle's flight, from route upload to landing, driven by its own telemetry in sim time.

    upload + verify -> (all vehicles) -> arm, take off -> (all vehicles airborne) -> OFFBOARD,
    yaw to the initial heading -> (all vehicles aligned) -> one planner tick per dt of the
    vehicle's sim clock -> at the station: hold, land

The control loop is event-driven: it waits for the next position sample (with a wall-clock bound
scaled by the measured speed factor), and ticks the shared :class:`VehiclePlanner` whenever the
vehicle's clock has passed the next tick time. Between ticks a keep-alive task resends the
current setpoint so that the autopilot's offboard-loss timer (sim time) never runs out at high
speed factors or on a lossy link. It never sends a setpoint computed from stale data: when
telemetry stops, the setpoint becomes a hover until it is fresh again, and a link that stays
silent ends the flight as ``link_lost``. An offboard-loss failsafe (PX4: "Failsafe activated",
then RTL or Hold per COM_OBL_RC_ACT) is recovered: setpoints keep flowing, PX4 re-enters OFFBOARD
by itself or is asked to, a bounded number of times.

Arming and take-off are in :mod:`companion.app.departure`, the tick and its setpoint in
:mod:`companion.app.steering`. Every way out of :meth:`Pilot.fly` that is not a landing at the
station leaves the vehicle safe: holding in the air (offboard stopped), or disarmed on the ground.
"""

from __future__ import annotations

import asyncio
import dataclasses
import time
from collections import deque
from collections.abc import Callable

from companion.app import monitors
from companion.app.context import FlightContext, PilotOutcome, RunSettings, wall_for_sim
from companion.app.departure import Departure
from companion.app.failsafe import (OVERRIDE_GRACE_MIN_WALL_S, OVERRIDE_GRACE_SIM_S, RECOVERABLE_MODES, FailsafeCause,
                                    FailsafeEvent, FailsafeWatch, ModeVerdict)
from companion.app.fence import upload_and_verify_fence
from companion.app.flight_plan import verify_readback
from companion.app.steering import Steering
from companion.errors import (CommandRefused, CompanionError, MissionAborted, MissionUploadError, TelemetryLost,
                              primary_error)
from uav_model.mission import VehicleSpec
from companion.vehicle.port import HOVER, FlightMode, LandedState, PoseSample, VelocityYawRateSetpoint

__all__ = ["FlightContext", "Pilot", "PilotOutcome", "RunSettings", "wall_for_sim"]

FENCE_NEAR_M = 5.0  # a failsafe this near the uploaded fence is its action (0.5 s of position lag at 10 m/s)
STALE_EXCUSES_S = 10.0  # wall: RTL this soon after our own telemetry gap is taken as the link-loss failsafe
# A telemetry gap this long (wall) may have been the link failing both ways; shorter ones are a busy
# machine. PX4 SITL counts COM_OF_LOSS_T (1 s) in wall time at any speed factor, as the stub does.
LINK_GAP_MIN_WALL_S = 0.5


class Pilot(Departure, Steering):
    def __init__(self, ctx: FlightContext, spec: VehicleSpec):
        self.ctx = ctx
        self.spec = spec
        self.name = spec.name
        self.vehicle = ctx.vehicles[spec.name]
        self.planner = ctx.setup.planners[spec.name]  # built with the others (FlightPlan.fleet_setup)
        self.outcome = PilotOutcome(spec.name)
        self.setpoint: VelocityYawRateSetpoint = HOVER
        self._offboard_live = False  # the keep-alive resends only while this is set
        self._next_progress_s = 0.0
        self._snapshot = ctx.field.from_tracks(())  # the obstacles as last seen by a tick
        self._failsafes = FailsafeWatch(self.vehicle.status())  # set again once OFFBOARD is confirmed
        self._stale_ended_wall: float | None = None
        self._reentries: deque[float] = deque()  # sim times of recent offboard re-entries

    # -- the whole flight ------------------------------------------------------------------
    async def fly(self) -> PilotOutcome:
        try:
            await self.vehicle.wait_ready(self.ctx.settings.ready_timeout_s)
            await self.upload_and_verify()
            await upload_and_verify_fence(self.vehicle, self.ctx.plan, self.ctx.report)  # a refusal: nothing armed
            self.outcome.phase = "uploaded"
            await self._barrier("all routes uploaded", self.ctx.settings.ready_timeout_s)
            await self._take_off()
            await self._barrier("all vehicles airborne", wall_for_sim(self.vehicle, self._climb_sim_s(), 30.0))
            await self._fly_offboard()
            await self._finish()
            return self.outcome
        except BaseException as exc:
            self.outcome.error = self.outcome.error or (str(exc) or type(exc).__name__)
            self.ctx.off_schedule.add(self.name)  # no longer flying its plan: the others' clocks stop waiting for it
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

    async def _fly_offboard(self) -> None:
        # Setpoints stream (keep-alive) from before the mode switch to the end, as PX4 requires.
        self.setpoint = HOVER
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
        await self._enter_offboard()
        self._failsafes = FailsafeWatch(self.vehicle.status())
        await self._align_heading()
        await self._barrier("all vehicles at their initial heading", wall_for_sim(self.vehicle, 60.0, 10.0))
        # Mission time starts when the companion sends its first planned command (the headless
        # runner's t = 0), from the pose that command was computed from.
        depart = self.vehicle.latest_pose()
        assert depart is not None
        self.outcome.phase = "offboard"
        self.outcome.t_depart_sim_s = self.ctx.departures[self.name] = depart.t_sim_s
        if self.ctx.departure_sim_s is None:  # the first to depart starts the schedule's clock for all
            self.ctx.departure_sim_s = depart.t_sim_s
        result = self._tick(depart)
        self.setpoint = self._setpoint(depart, result)[0]
        await self.vehicle.send_setpoint(self.setpoint)
        self._record(depart)
        self.ctx.report(f"{self.name}: OFFBOARD, departed at t_sim={depart.t_sim_s:.1f} s")
        await self._control_loop(depart)

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
                gap_wall = time.monotonic() - stale_since
                self.ctx.report(f"{self.name}: telemetry fresh again after {gap_wall:.2f} s wall")
                stale_since = None
                if gap_wall >= LINK_GAP_MIN_WALL_S:  # long enough to be the link, not a busy machine
                    self._stale_ended_wall = time.monotonic()
            pose = fresh
            self._record(pose)
            self._check_link_identity()
            await self._check_mode()
            if pose.t_sim_s + 1e-6 < next_tick and not self._at_station(pose):
                continue  # arrival is checked on every sample: a tick-only check can step past the radius
            next_tick += dt
            if next_tick <= pose.t_sim_s:  # samples came late: skip the ticks we missed
                next_tick = pose.t_sim_s + dt
            t_mission = self._mission_time(pose)
            if t_mission > self.ctx.mission.safety.time_limit_s:
                raise MissionAborted("timeout", f"time limit {self.ctx.mission.safety.time_limit_s:g} s reached",
                                     vehicle=self.name)
            result = self._tick(pose)
            if result.arrived:
                await self._hover()  # brake now: a lossy link may delay the HOLD below by seconds (docstring)
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
            if self.planner.detour_due:
                await self._detour(pose)

    async def _detour(self, pose: PoseSample) -> None:
        """No progress for a while: plan a new route from here in a worker thread (A* must not
        stall the other vehicle's loop), flying the setpoint just sent meanwhile."""
        x, y = pose.x_east_m, pose.y_north_m
        if getattr(self.vehicle, "clock_follows_event_loop", False):  # in-process: inline costs no sim time
            nodes = self.planner.plan_detour(x, y)
        else:
            nodes = await asyncio.to_thread(self.planner.plan_detour, x, y)
        if self.planner.adopt_detour(nodes, x, y, self._mission_time(pose)):
            self.outcome.interventions["planner: re-planned"] += 1
            self.ctx.report(f"{self.name}: no progress for {self.planner.detour_policy.after_s:g} s: "
                            f"new route from ({x:.0f}, {y:.0f}), {len(nodes)} nodes")
        else:
            self.outcome.interventions["planner: no new route"] += 1

    async def _on_stale(self, exc: TelemetryLost, first: bool, stale_wall_s: float) -> None:
        """Never fly on old data: hover, and give up when the silence lasts too long."""
        s = self.ctx.settings
        self.outcome.interventions["stale"] += 1
        await self._hover()
        if first:
            self.ctx.report(f"{self.name}: telemetry stale ({exc.message}); hovering")
            self.ctx.log.row(t_sim_s=self.vehicle.clock_s(), vehicle=self.name, phase="offboard",
                             action="hover", note=f"stale: {exc.message}")
        limit_wall = max(wall_for_sim(self.vehicle, s.link_lost_after_s, slack_s=1.0), s.link_lost_min_wall_s)
        if stale_wall_s > limit_wall:
            raise MissionAborted("link_lost", f"no fresh telemetry for {stale_wall_s:.1f} s wall", vehicle=self.name)

    def _check_link_identity(self) -> None:
        st = self.vehicle.status()
        if st.link_conflict is not None:
            raise MissionAborted("link_conflict", f"{st.link_conflict}; the second is not obeyed; holding",
                                 vehicle=self.name)
        why = st.link_anomaly
        if why is not None:
            raise MissionAborted("link_identity", f"{why}: another system answers with this vehicle's id; "
                                 "holding", vehicle=self.name)

    async def _check_mode(self) -> None:
        """OFFBOARD, or the autopilot's offboard-loss failsafe to recover from (bounded), or an
        operator's mode change to stand down for (companion.app.failsafe tells them apart)."""
        st = self.vehicle.status()
        recent_gap = self._stale_ended_wall is not None and time.monotonic() - self._stale_ended_wall < STALE_EXCUSES_S
        grace_wall = max(wall_for_sim(self.vehicle, OVERRIDE_GRACE_SIM_S, 0.0), OVERRIDE_GRACE_MIN_WALL_S)
        pose, fence = self.vehicle.latest_pose(), self.ctx.fence
        at_fence = None if fence is None or pose is None else fence.breach(pose.x_east_m, pose.y_north_m, FENCE_NEAR_M)
        verdict = self._failsafes.judge(st, self.vehicle.clock_s(), time.monotonic(), grace_wall, recent_gap, at_fence)
        if verdict is ModeVerdict.FENCE:
            if st.mode is FlightMode.OFFBOARD:  # the notice comes before the mode: wait for GF_ACTION's
                try:
                    await self.vehicle.wait_until(lambda s, p: s.mode is not FlightMode.OFFBOARD, grace_wall,
                                                  "the geofence action")
                except TelemetryLost:
                    pass  # GF_ACTION 1 (warning only): still in OFFBOARD
                st = self.vehicle.status()
            where = self._failsafes.fence_where
            notice = st.last_fence_text if where is None else f"no fence notice heard; the vehicle was {where}"
            self._note_failsafe(st.mode, FailsafeCause.GEOFENCE, notice)
            if st.mode is not FlightMode.OFFBOARD:
                self.outcome.phase = "geofence"  # the autopilot's fence action stands: nothing to send
            raise MissionAborted("geofence", f"the autopilot reported a geofence breach ({notice!r}) "
                                 f"and is in {st.mode.value}; companion stands down", vehicle=self.name)
        if verdict is ModeVerdict.FLYING and st.mode is FlightMode.OFFBOARD:
            self._recovered()  # OFFBOARD came back after a resume attempt that had given up waiting
        if verdict is ModeVerdict.RESUMED:
            # A failsafe that is already over: PX4 re-entered OFFBOARD by itself once setpoints flowed.
            self.outcome.offboard_reentries += 1
            self._note_failsafe(st.last_other_mode, FailsafeCause.OFFBOARD_LOSS, None)
            self._recovered()
            self.ctx.report(f"{self.name}: autopilot fell back to {st.last_other_mode.value} (offboard loss) "
                            "and re-entered OFFBOARD by itself")
        if verdict is ModeVerdict.OVERRIDE:
            # Someone else (a pilot, another failsafe) chose another mode: stop commanding, do not fight it.
            self.outcome.phase = "override"
            why = "by someone else (no failsafe)" if st.mode in RECOVERABLE_MODES else "by someone else or a failsafe"
            raise MissionAborted("override", f"mode changed to {st.mode.value} {why}; companion stands down",
                                 vehicle=self.name)
        if verdict is not ModeVerdict.RECOVER:
            return
        s = self.ctx.settings
        now = self.vehicle.clock_s() or 0.0
        while self._reentries and self._reentries[0] < now - s.offboard_reentry_window_s:
            self._reentries.popleft()
        if len(self._reentries) >= s.max_offboard_reentries:
            raise MissionAborted("link_lost", f"offboard lost {len(self._reentries)} times in "
                                 f"{s.offboard_reentry_window_s:g} s; left in {st.mode.value}", vehicle=self.name)
        self._reentries.append(now)
        if not self.outcome.failsafes or self.outcome.failsafes[-1].recovered:
            self._note_failsafe(st.mode, FailsafeCause.OFFBOARD_LOSS, None)
        await self._resume_offboard(st.mode)

    def _note_failsafe(self, mode: FlightMode | None, cause: FailsafeCause, notice: str | None) -> None:
        t = self.vehicle.clock_s()
        depart = self.outcome.t_depart_sim_s
        self.outcome.failsafes.append(FailsafeEvent(
            self.name, t, None if t is None or depart is None else t - depart,
            mode.value if mode is not None else "unknown", cause, recovered=False, notice=notice))

    def _recovered(self) -> None:
        """OFFBOARD is back: the latest failsafe is over."""
        if self.outcome.failsafes and not self.outcome.failsafes[-1].recovered:
            self.outcome.failsafes[-1] = dataclasses.replace(self.outcome.failsafes[-1], recovered=True)

    async def _resume_offboard(self, mode: FlightMode) -> None:
        """The autopilot's offboard-loss failsafe: setpoints were late. Keep streaming (a hover:
        the last command was computed before the gap) and resume OFFBOARD, visibly."""
        s = self.ctx.settings
        self.outcome.offboard_reentries += 1
        self.ctx.report(f"{self.name}: autopilot fell back to {mode.value} (offboard loss); resuming OFFBOARD "
                        f"({len(self._reentries)}/{s.max_offboard_reentries} in {s.offboard_reentry_window_s:g} s)")
        self.setpoint = HOVER
        try:  # PX4 re-enters OFFBOARD by itself once setpoints flow again; if it is slow, ask
            await self.vehicle.wait_until(lambda st, p: st.mode is FlightMode.OFFBOARD,
                                          wall_for_sim(self.vehicle, s.offboard_resume_wait_s, 0.05), "OFFBOARD")
        except TelemetryLost:
            try:
                await self._retry("offboard start", lambda: self.vehicle.start_offboard(self.setpoint))
                await self.vehicle.wait_until(lambda st, p: st.mode is FlightMode.OFFBOARD,
                                              wall_for_sim(self.vehicle, 5.0), "OFFBOARD mode")
            except (CommandRefused, TelemetryLost) as exc:
                # Refused (setpoints not yet flowing again) or lost again at once: the next
                # sample's mode check makes another attempt, within the bound.
                self.ctx.report(f"{self.name}: OFFBOARD not resumed yet ({exc.message})")
                return
        self._failsafes.offboard_confirmed(self.vehicle.status())
        self._recovered()

    async def _finish(self) -> None:
        """Hold at the station, then land. The flight has succeeded by now (SPEC §2 asks for the
        arrival): a refused landing is reported, and leaves the vehicle holding, not a failure."""
        recorder = asyncio.create_task(self._record_until_landed(), name=f"{self.name}:track after arrival")
        try:
            await self._hold_and_land()
        except CompanionError as exc:
            self.outcome.error = str(exc)
            self.ctx.report(f"{self.name}: after arrival: {exc}; left in {self.vehicle.status().mode.value}")
        finally:
            recorder.cancel()

    async def _hold_and_land(self) -> None:
        if self.vehicle.status().mode is FlightMode.OFFBOARD:  # once more: the keep-alive has stopped
            await self._hover()
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

