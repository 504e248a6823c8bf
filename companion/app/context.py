"""What every pilot of one mission shares: the settings, the plan, the log, the planners and schedule clocks, a barrier.

Split from :mod:`companion.app.pilot` so that its phases (take-off, steering) can live in their
own modules and read the same context.
"""

from __future__ import annotations

import asyncio
import math
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from companion.app.failsafe import FailsafeEvent
from companion.app.flight_log import FlightLog
from companion.app.fence import FenceGeometry
from companion.app.flight_plan import FlightPlan
from companion.planning.obstacle_field import ObstacleField
from companion.planning.coordination.replan import ReplanJob, Replanned
from companion.planning.coordination.clocks import KeptHold
from companion.vehicle.mavsdk_vehicle import STREAM_RATE_HZ
from companion.vehicle.port import PoseSample, Vehicle

if TYPE_CHECKING:
    from companion.app.pilot import Pilot


@dataclass(frozen=True)
class RunSettings:
    """How the runner flies; every duration says whether it is sim or wall time."""

    shared_clock: bool | None = None  # one sim clock for all vehicles; None: detect it at connect
    connect_timeout_s: float = 15.0  # wall
    telemetry_hz: float = STREAM_RATE_HZ  # attitude, position and velocity asked of each autopilot, of its own clock
    ready_timeout_s: float = 30.0  # wall
    command_attempts: int = 5  # retryable answers only (TIMEOUT, BUSY): a loaded machine times MAVSDK transfers out
    progress_every_s: float = 20.0  # sim
    lookahead_s: float = 2.0  # sim, safety monitors
    link_lost_after_s: float = 10.0  # sim, continuous silence before the flight is abandoned ...
    link_lost_min_wall_s: float = 5.0  # ... and at least this long in wall time: PX4 SITL stretches its own
    # loss timeouts by the speed factor, so at 20x a 3 s gap is a failsafe to resume from, not the end
    keepalive_sim_s: float = 0.1  # sim, setpoint resend period (bounded to 10..100 ms wall)
    max_offboard_reentries: int = 10  # within offboard_reentry_window_s: a link that keeps failing ends the flight
    offboard_reentry_window_s: float = 60.0  # sim
    offboard_entry_s: float = 15.0  # sim: OFFBOARD asked for (again) this long before the flight gives up
    offboard_resume_wait_s: float = 0.5  # sim: a grace for PX4's own re-entry (0.2-3 s) before asking for it
    arm_retry_s: float = 15.0  # sim: PX4 refuses to arm for ~4.2 s after boot (TEMPORARILY_REJECTED)
    yaw_align_tolerance_deg: float = 10.0
    land: bool = True
    failsafe_hold: bool = True  # set COM_OBL_RC_ACT 5 at connect: PX4's default RTL flies straight home,
    # through the obstacles only the companion knows about
    safe_state_timeout_s: float = 5.0  # wall
    signing_key: bytes | None = field(default=None, repr=False)  # MAVLink 2 signing on every udpin link


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
    failsafes: list[FailsafeEvent] = field(default_factory=list)  # every failsafe the autopilot took in flight
    arm_attempts: int = 0
    ticks: int = 0
    error: str | None = None


class FlightContext:
    """What the pilots share: the plan, the settings, the log, the planners and schedule clocks, one barrier."""

    def __init__(self, plan: FlightPlan, settings: RunSettings, log: FlightLog,
                 vehicles: Mapping[str, Vehicle], report: Callable[[str], None], shared_clock: bool = True):
        self.plan = plan
        self.mission = plan.mission
        self.settings = settings
        self.shared_clock = shared_clock  # decided at connect (readiness.detect_shared_clock)
        self.log = log
        self.vehicles = dict(vehicles)
        self.report = report
        self.field = ObstacleField.from_world(plan.mission.world)
        self.fence = FenceGeometry(plan.mission) if plan.geofence else None  # what was uploaded, if anything
        self.barrier = asyncio.Barrier(len(self.vehicles))
        self.arrived: set[str] = set()  # vehicles parked at their station: others drop the sightline term
        self.departure_sim_s: float | None = None  # the common departure (t = 0 of the schedule), set by the first pilot
        # Every vehicle's planner and the timed routes' clocks, built as the headless runner builds them.
        self.setup = plan.fleet_setup()
        self.clocks = self.setup.clocks if shared_clock else None  # unrelated clocks: no common schedule
        self.off_schedule: set[str] = set()  # no longer flying its plan (failed, stood down): holds nobody back
        self.departures: dict[str, float] = {}  # each vehicle's departure on its own clock
        # Unrelated clocks: the first vehicle's departure hold is kept against the lower vehicles instead.
        self.kept_hold = None if shared_clock else self._kept_hold()
        self.worst_lag_s = 0.0  # how far behind sim time a schedule clock fell, at most
        self._observed: dict[str, float] = {}  # per vehicle: the sim time of its last sample given to the clocks
        self.replan_task: asyncio.Task | None = None  # the in-flight re-plan of a lagging vehicle: at most one
        self.replan_errors = 0  # re-plans that raised (the vehicles flew on with their old plans)
        # In-process vehicles: their sim clock follows the event loop, so a re-plan inline costs no sim time.
        self._inline = all(getattr(v, "clock_follows_event_loop", False) for v in self.vehicles.values())
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
        if self.shared_clock:
            return t_sim_s
        return t_sim_s - (pilot.outcome.t_depart_sim_s or 0.0)

    def schedule_time(self, pilot: "Pilot", pose: PoseSample) -> float:
        """The time ``pilot`` reads its timed route at. On the shared sim clock (the one the
        obstacles and the other vehicles live in): seconds since the common departure, as the
        timed routes are planned, read at the clocks the headless runner reads them at
        (``setup.clocks``: for a lower vehicle, held back while the vehicles above it lag their
        plans), after every vehicle's latest sample has been given to them. Per vehicle since its
        own departure when the vehicles' clocks are unrelated; there, with no clocks to share, the
        first vehicle's departure hold is kept against the vehicles below it (``timed.KeptHold``)."""
        if not (self.shared_clock and self.departure_sim_s is not None):
            t = pose.t_sim_s - (pilot.outcome.t_depart_sim_s or pose.t_sim_s)
            return self._held(pilot.name, t) if self.kept_hold is not None and not self.rank[pilot.name] else t
        t = pose.t_sim_s - self.departure_sim_s
        if self.clocks is None:
            return t
        self._observe_fleet()
        self._start_replan(t)
        tau = self.clocks.now(pilot.name, t)
        self.worst_lag_s = max(self.worst_lag_s, t - tau)
        return tau

    def _kept_hold(self) -> KeptHold | None:
        co = self.plan.coordinated
        if co is None or co.hold_s <= 0:
            return None
        first, *below = (v.name for v in self.mission.by_priority)
        return KeptHold(co.timed[first], {n: co.timed[n] for n in below if n in co.timed},
                        self.setup.coordination.hold_s_max - co.hold_s)

    def _held(self, first: str, t: float) -> float:
        """The first vehicle's schedule time, its hold kept against the lower vehicles (each
        observed on its own clock since its own departure)."""
        kept = self.kept_hold
        assert kept is not None
        for name, vehicle in self.vehicles.items():
            pose, depart = vehicle.latest_pose(), self.departures.get(name)
            if name == first or pose is None or depart is None:
                continue
            if name in self.arrived or name in self.off_schedule:
                kept.done(name)
            else:
                kept.observe(name, (pose.x_east_m, pose.y_north_m), pose.t_sim_s - depart)
        fixed = kept.extra_s is not None
        tau = kept.now(t)
        if not fixed and kept.extra_s is not None and kept.extra_s > 0.5:
            self.report(f"{first}: departs {kept.extra_s:.1f} s after its planned hold of {kept.departure_s:.1f} s: "
                        "the vehicles below it are behind their plans")
        return tau

    def _observe_fleet(self) -> None:
        """Give the clocks each vehicle's newest position sample, at that sample's own sim time
        (the vehicles report asynchronously), as the headless runner gives them every flying
        vehicle's position each tick; a vehicle that has arrived or left its plan is done."""
        assert self.clocks is not None and self.departure_sim_s is not None
        for name, vehicle in self.vehicles.items():
            if name in self.arrived or name in self.off_schedule:
                self.clocks.done(name)
                continue
            pose = vehicle.latest_pose()
            if pose is None or pose.t_sim_s <= self._observed.get(name, -math.inf):
                continue  # nothing new: a stale vehicle holds the clocks back no longer than they allow
            self._observed[name] = pose.t_sim_s
            self.clocks.observe(name, (pose.x_east_m, pose.y_north_m), pose.t_sim_s - self.departure_sim_s)

    def _start_replan(self, t_s: float) -> None:
        """Re-plan a lower vehicle that lags its plan (:class:`companion.planning.coordination.replan.ScheduleClocks`,
        as the headless runner does each tick): the cheap check here, the planning (seconds of
        CPU) in a worker thread, the new routes adopted back on the loop when it is done. At most
        one in flight; none outside a running loop (a pilot ticked by hand)."""
        assert self.clocks is not None
        if self.replan_task is not None:
            return
        try:
            asyncio.get_running_loop()
        except RuntimeError:
            return
        job = self.clocks.job(t_s)
        if job is None:
            return
        if self._inline:
            self._adopt(job, self.clocks.plan(job))
        else:
            self.replan_task = asyncio.create_task(self._replan(job), name=f"re-plan {'+'.join(job.names)}")

    async def _replan(self, job: ReplanJob) -> None:
        assert self.clocks is not None
        try:
            planned = await asyncio.to_thread(self.clocks.plan, job)
        except Exception as exc:  # a bug in the planner must not end the flight: the old plan still flies
            self.replan_errors += 1
            self.report(f"re-plan of {'+'.join(job.names)} at t = {job.t_s:.1f} s failed ({exc!r}): "
                        f"flying on with the old plan")
            return
        finally:
            self.replan_task = None
        self._adopt(job, planned)

    def _adopt(self, job: ReplanJob, planned: "list[Replanned]") -> None:
        """Install a re-plan's routes on the loop; one for a vehicle no longer flying is dropped."""
        assert self.clocks is not None
        flying = [p for p in planned if p.name not in self.arrived and p.name not in self.off_schedule]
        for name, route in self.clocks.adopt(job, flying).items():
            self.setup.planners[name].adopt_timed(route, self.clocks.sight_near_m(name))
            self.report(f"{name}: behind its plan: re-planned from t = {job.t_s:.1f} s, "
                        f"arrives at {route.t_s[-1]:.1f} s")


# A wall bound for sim work still stands when the sim runs at half its measured rate: a loaded
# machine slows PX4 SITL's clock, and the estimate follows that with a window's delay.
SIM_SLOWDOWN_MARGIN = 2.0


def wall_for_sim(vehicle: Vehicle, sim_s: float, slack_s: float = 5.0) -> float:
    """A wall-clock bound for something that takes ``sim_s`` of the vehicle's sim time, at the
    measured speed factor (1x while unknown), with room for the sim to slow down."""
    rate = vehicle.sim_rate()
    rate = rate if rate is not None and rate > 0.05 else 1.0
    return SIM_SLOWDOWN_MARGIN * sim_s / rate + slack_s
