"""One vehicle's planner, the per-tick code the headless runner and the live companion both call:

    planner = VehiclePlanner.build(mission, vehicle, route, variant)
    result = planner.tick(own_pose, other_uav, snapshot, t_s)   # snapshot: see obstacle_field

It holds the local-goal tracking along the route (:mod:`.local_goals`, paper section V), one BDWA
step a tick (:mod:`.dwa`), and the detour after a stall; what each variant flies is :mod:`.variants`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from companion.planning.dwa import Command, DwaConfig, NoLegalRollout, ObstacleSnapshot, OtherUav, Pose, plan_step
from companion.planning.dwa.legality import separation_reach
from companion.planning.dwa.types import slots_constructor
from companion.planning.errors import BudgetExceeded, NoPath
from companion.planning.grid import rasterise
from companion.planning.local_goals import LocalGoalTracker
from companion.planning.routes import detour_route
from companion.planning.variants import VARIANTS, GoalSource, approach_config, variant_nodes, window_settings
from uav_model.world import World
from uav_model.fence_margin import rollout_box
from uav_model.plant import TRACKING_LAG_S

if TYPE_CHECKING:
    from uav_model.mission import Mission, VehicleSpec
    from companion.planning.routes import Route
    from companion.planning.timed_route import TimedRoute


@dataclass(frozen=True, slots=True)
class TickResult:
    """What one vehicle does this tick. ``command`` is None when it must hold (zero speed); a
    recovery command has speed 0 and a yaw rate (yaw in place: BODY velocity 0 + yawspeed)."""

    t_s: float
    command: Command | None
    local_goal_xy: tuple[float, float]
    goal_index: int
    arrived: bool
    planner_ms: float
    hold_reason: str | None = None  # why command is None
    escape_reason: str | None = None  # no rollout was legal for the whole horizon: flying the longest-lasting
    recovery_reason: str | None = None  # no rollout legal from this heading: yawing in place (speed 0) to one

    @property
    def yaw_rate_rad_s(self) -> float:
        return 0.0 if self.command is None else self.command.yaw_rate_rad_s

    @property
    def speed_m_s(self) -> float:
        return 0.0 if self.command is None else self.command.speed_m_s


_make_result = slots_constructor(TickResult)  # TickResult(*values), every field given: every tick makes one
_AIM_FRACTION = 0.5  # of the arrival radius, aimed at by a speed window (see VehiclePlanner)
# A vehicle this far behind its timed plan flies it without the sightline term: the term had
# it hover where the line was blocked while the plan moved on (stalls of 40-60 s, b hundreds of
# metres behind its plan, and the real closest approach then where no plan had it).
SIGHT_LAG_M = 50.0
_PROGRESS_M = 20.0  # the remaining route must shorten by more than this to count as progress
# How far a vehicle may run ahead of its pace (VehiclePlanner.pace) along it: half a second at
# cruise, and far more than a flight read against its own forecast ever leads it (the forecast
# keeps every second tick's position: its along-track error is centimetres).
PACE_LEAD_M = 5.0


@dataclass(frozen=True)
class DetourPolicy:
    """How an A*-guided vehicle gets out of a pocket (nav2 re-plans its global path for the same
    reason): when its remaining route has not shortened by more than 20 m for ``after_s`` sim
    seconds, a new route is planned from where it is (:func:`routes.detour_route`)."""

    after_s: float
    world: World
    resolution_m: float
    sparse: bool  # sparse nodes (astar-bdwa) or every A* cell (astar-bdwa-nosparse)
    earlier: tuple["Route", ...] = ()  # higher-priority routes: the detour keeps the priority rule first
    separation_m: float = 0.0


class VehiclePlanner:
    """One vehicle's A*-BDWA (or ablation variant): local-goal tracking + one BDWA step a tick.

    A stall detour is split so that a live caller never blocks its event loop on A*: ``tick`` sets
    ``detour_due``; the caller runs :meth:`plan_detour` (pure, a few tens of ms; in a worker
    thread if it likes) and hands the result to :meth:`adopt_detour`. The headless runner does
    both at once, right after the tick that set the flag.
    """

    def __init__(self, name: str, config: DwaConfig, tracker: LocalGoalTracker, arrival_radius_m: float,
                 detour_policy: DetourPolicy | None = None, timed_route: "TimedRoute | None" = None,
                 approach: DwaConfig | None = None, sight_near_m: float | None = None,
                 pace: "TimedRoute | None" = None):
        self.name = name
        self.timed_route = timed_route  # when given, flown on schedule (a speed window is needed)
        # A plan it must not run ahead of by more than PACE_LEAD_M (see _schedule): with a timed route only.
        self.pace = pace if timed_route is not None else None
        self._pace_along_m: float | None = None
        self.config = config
        self.tracker = tracker
        self.arrival_radius_m = arrival_radius_m
        # With a speed window the rollouts aim inside half the arrival radius: the multicopter's
        # velocity lags its heading, so a rollout that just grazes the circle is flown just outside
        # it, tick after tick (a station circled at 20.5-21 m with a 20 m radius; the paper's
        # constant-speed window keeps the whole radius).
        self._aim_radius_m = arrival_radius_m * (_AIM_FRACTION if config.count > config.samples else 1.0)
        # The final approach (see approach_config): flown within a turning diameter plus the
        # arrival radius of the station, aiming inside half the radius as any speed window does.
        self.approach = approach
        self._approach_radius_m = (-math.inf if approach is None
                                   else 2.0 * approach.speed_m_s / approach.max_yaw_rate_rad_s + arrival_radius_m)
        # With a timed route the plan decides where the sight line is blocked; the sightline term
        # only acts within ``sight_near_m`` of the other UAV (around the closest approach). Farther
        # out it pulled b hundreds of metres off its timed path to hide from a distant a, and the
        # plan's timing was lost where it mattered.
        self.sight_near_m = sight_near_m
        self._along_m: float | None = None  # how far along its timed path it is (windowed: timed_route.progress_window)
        # Local goals are the timed path's nodes: they advance with the progress along it (below).
        self._goals_on_path = timed_route is not None and np.array_equal(tracker.nodes, timed_route.path_xy)
        self.lead_m = 0.0  # how far ahead of its timed plan it is (negative: it lags)
        self._unsighted = None if sight_near_m is None or config.w_s <= 0 else replace(config, w_s=0.0)
        self.arrived = False
        self.detour_policy = detour_policy if detour_policy is not None and detour_policy.after_s > 0 else None
        self.detour_due = False
        self.detours = 0  # how many detours were planned after a stall (adopted or not)
        self._progress: tuple[float, float] | None = None  # (best remaining route m, sim time it was reached)
        self._grid = None  # the static grid, rasterised at the first detour
        self._turning_to: float | None = None  # the heading a yaw in place set out for (spin recovery)
        self._station_xy = (float(tracker.nodes[-1][0]), float(tracker.nodes[-1][1]))

    @classmethod
    def build(cls, mission: "Mission", vehicle: "VehicleSpec", route: "Route | None",
              variant: str | None = None, *, earlier: "Iterable[Route]" = (),
              timed_route: "TimedRoute | None" = None, sight_near_m: float | None = None,
              pace: "TimedRoute | None" = None) -> "VehiclePlanner":
        """The planner for ``vehicle``; ``route`` is required for the A* variants. ``earlier``:
        the routes of the vehicles above it (:func:`routes.higher_routes`), which a detour after a
        stall keeps to the priority rule first. ``timed_route`` (arrival times along the route) is
        tracked by the timed variant and ignored by the others; ``pace``, with it, a plan the
        vehicle must not run ahead of (:attr:`.coordination.plan.CoordinatedPlan.first_tracks`).

        Priority (paper §II.B: the UAV leaving A "is prioritized to arrive"): the first vehicle in
        priority order has right of way and flies without the sightline term; every other
        vehicle carries the sightline objective and bends its path to keep the sight line
        occluded. Separation is enforced by all of them.
        """
        variant = variant or mission.planner.variant
        spec = VARIANTS[variant]
        goals_from = spec.goals
        sightline = spec.sightline and mission.carries_sightline(vehicle.name)
        nodes = variant_nodes(variant, vehicle, route)
        # Keep-in box: the area, and of the geofence margin what keeps the braking distance and
        # the tracking lag from the uploaded fence (uav_model.fence_margin).
        fence = rollout_box(mission, vehicle)
        window = window_settings(mission, variant)
        if not sightline:
            del window["w_s"]  # the first in priority flies without the term
        config = DwaConfig.from_settings(mission.planner, vehicle, mission.safety, sightline=sightline, fence_m=fence,
                                         tracking_lag_s=TRACKING_LAG_S[mission.plant], **window)
        tracker = LocalGoalTracker(nodes, mission.planner.acceptance_radius_m)
        detour_policy = None if goals_from is GoalSource.STATION else DetourPolicy(
            mission.planner.replan_after_s, mission.world, mission.planner.grid_resolution_m,
            goals_from is GoalSource.SPARSE, tuple(earlier), mission.safety.min_separation_m)
        timed = timed_route if spec.timed and config.count > config.samples else None
        if timed is not None and len(timed.path_xy) >= 2:
            # Fly where the plan is timed: its space-time path may leave the A* route by a
            # kilometre (another side of an obstacle), and its times mean nothing elsewhere.
            tracker = LocalGoalTracker(timed.path_xy, mission.planner.acceptance_radius_m)
        return cls(vehicle.name, config, tracker, mission.safety.arrival_radius_m, detour_policy, timed,
                   approach_config(mission, config), sight_near_m if timed is not None else None, pace)

    def plan_detour(self, x_m: float, y_m: float) -> np.ndarray | None:
        """A new route from (x, y) to the station, or None when there is none. Reads only what
        does not change while flying (and caches the grid), so it may run in a worker thread."""
        if self.detour_policy is None:
            return None
        r = self.detour_policy
        if self._grid is None:
            self._grid = rasterise(r.world, r.resolution_m)
        try:
            return detour_route(self._grid, r.world, (x_m, y_m), self._station_xy, sparse=r.sparse,
                                earlier=r.earlier, separation_m=r.separation_m)
        except (NoPath, BudgetExceeded):
            return None

    def adopt_detour(self, nodes: np.ndarray | None, x_m: float, y_m: float, t_s: float) -> bool:
        """Fly ``nodes`` (from :meth:`plan_detour`) from now on; with None keep the route and
        wait another ``after_s`` before trying again. Returns whether the route changed."""
        self.detour_due = False
        self.detours += 1
        adopted = nodes is not None and len(nodes) >= 2
        if adopted:
            self.tracker = LocalGoalTracker(nodes, self.tracker.acceptance_radius_m)
            self.timed_route = self.pace = None  # off the timed path: its times no longer apply; cruise
        self._progress = (self.tracker.remaining_m(x_m, y_m), t_s)
        return adopted

    def adopt_timed(self, route: "TimedRoute", sight_near_m: float | None) -> None:
        """Track ``route`` from now on (an in-flight re-plan, :class:`replan.ScheduleClocks`): its
        path's nodes as local goals, its times for the speed, its closest approach for where the
        sightline term acts. A planner that tracks no timed route (another variant) ignores it."""
        if self.timed_route is None or len(route.path_xy) < 2:
            return
        self.timed_route = route
        self._along_m, self.lead_m = None, 0.0
        self.tracker = LocalGoalTracker(route.path_xy, self.tracker.acceptance_radius_m)
        self._goals_on_path = True
        if self._unsighted is not None and sight_near_m is not None:
            self.sight_near_m = sight_near_m
        self._progress = None

    def _watch_progress(self, x_m: float, y_m: float, t_s: float, on_schedule: bool) -> None:
        """Flag a detour after ``after_s`` without progress. Time the schedule holds the vehicle
        back (a scheduled wait, or the plan ahead of it) is not a stall: the clock restarts."""
        remaining = self.tracker.remaining_m(x_m, y_m)
        if self._progress is None or on_schedule or remaining < self._progress[0] - _PROGRESS_M:
            self._progress = (remaining, t_s)
        elif t_s - self._progress[1] >= self.detour_policy.after_s:
            self.detour_due = True

    def _schedule(self, own: Pose, t_s: float) -> tuple[float | None, bool]:
        """The speed the timed route asks for now (None: no route, cruise) and whether the
        schedule holds the vehicle (a scheduled wait, or ahead of the plan along its path: only
        then is standing still no stall; a vehicle that lags its plan still detours after a stall)."""
        route = self.timed_route
        if route is None:
            return None, False
        # Where it is along its path (near where it was), the speed that keeps it on time, its lead.
        self._along_m, speed, self.lead_m, waiting = route.schedule_of(own.x_m, own.y_m, t_s, self.config.speed_m_s,
                                                                       self._along_m)
        if self.pace is not None:
            # More than PACE_LEAD_M ahead of its pace, it flies the pace's schedule instead (no
            # faster than its own). Where it flies as its pace was flown, it is never that far ahead.
            self._pace_along_m, paced, lead_m, _ = self.pace.schedule_of(own.x_m, own.y_m, t_s, self.config.speed_m_s,
                                                                        self._pace_along_m)
            if lead_m > PACE_LEAD_M:
                speed, waiting = min(speed, paced), True
        if self._goals_on_path:
            # A space-time path can step out and back (a cell or a few beside a wait, round a
            # shadow's edge); the multicopter cuts such a corner and never reaches the node, so
            # the tracker held it as the goal and b turned back to it, hovering 10 s or more near the
            # closest approach. The goal is past wherever b is along the path.
            self.tracker.advance_to(self._along_m)
        return speed, self.lead_m > 0.0 or waiting

    @property
    def separation_reach(self) -> tuple[float, float]:
        """:func:`.dwa.legality.separation_reach` over every config this planner may fly."""
        reaches = [separation_reach(c) for c in (self.config, self.approach) if c is not None]
        return max(r[0] for r in reaches), max(r[1] for r in reaches)

    @property
    def station_xy(self) -> tuple[float, float]:
        return self._station_xy

    def tick(self, own: Pose, other: OtherUav | None, snapshot: ObstacleSnapshot, t_s: float,
             schedule_t_s: float | None = None, separate_from: Sequence[OtherUav] | None = None) -> TickResult:
        """Decide this tick's command from the current own pose, other UAV and obstacles.
        ``schedule_t_s``: the time to read the timed route at, when it is not ``t_s`` (the live
        companion's schedule clock, which may pause and jump; the progress watchdog keeps ``t_s``).
        ``other`` is the sightline partner; ``separate_from`` every UAV to keep separated from
        (None: ``other`` alone; see :mod:`companion.planning.fleet`).

        Once inside the arrival radius the vehicle has arrived for good and holds.
        """
        started = time.perf_counter()
        to_station_m, scheduled = self._advance(own, t_s, schedule_t_s)
        if self.arrived:
            return TickResult(t_s, None, self.station_xy, self.tracker.index, True,
                              (time.perf_counter() - started) * 1e3, "arrived")
        goal = self.tracker.goal_xy
        config, aim_m = self.config, self._aim_radius_m
        if self._unsighted is not None and self.timed_route is not None and other is not None and \
                (math.hypot(other.x_m - own.x_m, other.y_m - own.y_m) > self.sight_near_m
                 or self.lead_m < -SIGHT_LAG_M):
            config = self._unsighted
        if to_station_m <= self._approach_radius_m:
            config, aim_m = self.approach, self.arrival_radius_m * _AIM_FRACTION
        reach = config.reach_m + self.tracker.acceptance_radius_m
        goals = self.tracker.window(own.x_m, own.y_m, reach, aim_m)
        decision = plan_step(own, goals, other, snapshot, config, scheduled, separate_from)
        ms = (time.perf_counter() - started) * 1e3
        if isinstance(decision, NoLegalRollout) and decision.recovery is not None:
            command, why = self._keep_turning(own, decision, config)
            return TickResult(t_s, command, goal, self.tracker.index, False, ms, recovery_reason=why)
        self._turning_to = None
        if isinstance(decision, NoLegalRollout):
            if decision.escape is not None:
                return TickResult(t_s, decision.escape, goal, self.tracker.index, False, ms, None, decision.reason)
            return TickResult(t_s, None, goal, self.tracker.index, False, ms, decision.reason)
        return _make_result(t_s, decision, goal, self.tracker.index, False, ms, None, None, None)

    def _advance(self, own: Pose, t_s: float, schedule_t_s: float | None) -> tuple[float, float | None]:
        """What a tick keeps before it decides: arrival (then nothing else), the local goal, the
        schedule and the progress watch. Returns the distance to the station and the speed the
        schedule asks for (None: cruise)."""
        sx, sy = self.station_xy
        to_station_m = math.hypot(own.x_m - sx, own.y_m - sy)
        if self.arrived or to_station_m <= self.arrival_radius_m:
            self.arrived, self._turning_to = True, None
            return to_station_m, None
        self.tracker.update(own.x_m, own.y_m)
        scheduled, held = self._schedule(own, t_s if schedule_t_s is None else schedule_t_s)
        if self.detour_policy is not None and not self.detour_due:
            self._watch_progress(own.x_m, own.y_m, t_s, held)
        return to_station_m, scheduled

    def follow(self, own: Pose, t_s: float, schedule_t_s: float | None, decided: TickResult) -> bool:
        """Keep what :meth:`tick` would keep from ``own`` at ``t_s``, where it decided ``decided``
        (known already: a flight recorded, :mod:`.flight.replay`), without deciding again. A
        spin recovery's heading depends on the decision itself: returns False, keeping nothing,
        for a tick that recovered (call :meth:`tick` for it)."""
        if decided.recovery_reason is not None:
            return False
        self._advance(own, t_s, schedule_t_s)
        self._turning_to = None
        return True

    def _keep_turning(self, own: Pose, decision: NoLegalRollout, config: DwaConfig) -> tuple[Command, str]:
        """A yaw in place keeps its way round until it faces the heading it set out for.

        Each tick the spin recovery picks the best heading afresh, and two headings on either
        side of the vehicle can score within a hair of each other (the goal straight behind it):
        picked by turns, the vehicle yaws one tick left, one tick right, and never faces either
        (a vehicle outside the fence, every rollout from its heading leading further out, turned
        in place until the time limit). So while the heading set out for is more than a tick's
        yaw away, a pick that turns the other way is overruled: the yaw in place is judged safe
        by the hover check whatever the heading, and on arrival the window decides afresh."""
        command, target = decision.recovery, own.heading_rad + decision.turn_rad
        before = self._turning_to
        if before is not None and command is not None:
            left = math.remainder(before - own.heading_rad, math.tau)
            tick = config.max_yaw_rate_rad_s * config.dt_s
            if abs(left) > tick + 1e-9 and left * command.yaw_rate_rad_s < 0.0:
                rate = math.copysign(config.max_yaw_rate_rad_s, left)
                return (replace(command, yaw_rate_rad_s=rate),
                        f"{decision.reason}; kept turning {math.degrees(left):+.0f} deg to the heading set out for")
        self._turning_to = target
        return command, decision.reason
