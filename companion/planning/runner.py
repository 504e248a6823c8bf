"""Headless in-process runner: every vehicle flown by its VehiclePlanner on the shared plant.

No sockets and no clocks: the same per-tick planner code the live companion runs
(:class:`VehiclePlanner.tick` on an :class:`ObstacleSnapshot` of the obstacles' state *now*),
the same plant as the SITL stub (:func:`sim_bridge.kinematics.step`, fed a BODY_NED velocity and
a PX4 yawspeed converted by :mod:`companion.frames`), and the same scoring as every other flight
(:func:`companion.planning.metrics.summarize`).

The loop ticks at the planner's dt. All vehicles decide from the state at t, then all step.
A vehicle inside its arrival radius has arrived: it is frozen there and its track ends. A
vehicle whose planner finds no legal rollout hovers that tick. The run stops at the first
collision (checked along each step's segment against the true footprints, moving ones where
they really are), separation or geofence violation, when everyone has arrived, or at the time
limit.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from companion.frames import enu_heading_to_ned_yaw, enu_yaw_rate_to_ned, ned_yaw_to_enu_heading
from companion.mission import Mission
from companion.planning.dwa import OtherUav, Pose
from companion.planning.fusion import ObstacleField, TickResult, VehiclePlanner, variant_needs_route
from companion.planning.metrics import (RunSummary, Track, TruthGeometry, inside_fence,
                                        pair_min_distance, summarize)
from sim_bridge.kinematics import HOVER, KinematicState, VehicleLimits, VelocityCommand, VelocityFrame, step

from companion.planning.routes import Route, plan_routes


@dataclass(frozen=True)
class RunResult:
    """A finished headless flight: what was planned, what was flown, how it scored."""

    mission: Mission
    variant: str
    routes: dict[str, Route]
    tracks: dict[str, Track]
    ticks: dict[str, list[TickResult]]
    summary: RunSummary
    wall_s: float

    @property
    def success(self) -> bool:
        return self.summary.success

    @property
    def speed_factor(self) -> float:
        """Simulated seconds per wall-clock second."""
        return self.summary.duration_s / self.wall_s if self.wall_s > 0 else math.inf


def body_command(yaw_rate_enu_rad_s: float, speed_m_s: float) -> VelocityCommand:
    """The planner's (ENU yaw rate, forward speed) as PX4's BODY_NED setpoint."""
    return VelocityCommand(VelocityFrame.BODY_NED, speed_m_s, 0.0, 0.0,
                           enu_yaw_rate_to_ned(yaw_rate_enu_rad_s))


def _pose(s: KinematicState) -> Pose:
    return Pose(s.east_m, s.north_m, ned_yaw_to_enu_heading(s.yaw_rad))


def _other(s: KinematicState) -> OtherUav:
    return OtherUav(s.east_m, s.north_m, s.ve_m_s, s.vn_m_s)


def simulate(mission: Mission, variant: str | None = None, *,
             routes: dict[str, Route] | None = None) -> RunResult:
    """Fly ``mission`` headless with ``variant`` (default: the mission's) and score it.

    Raises :class:`companion.planning.errors.NoPath` when an A* variant finds no route.
    """
    started = time.perf_counter()
    if variant is not None:
        mission = mission.with_variant(variant)
    variant = mission.planner.variant
    if routes is None:
        routes = plan_routes(mission) if variant_needs_route(variant) else {}
    vehicles = mission.by_priority
    planners = {v.name: VehiclePlanner.build(mission, v, routes.get(v.name), variant) for v in vehicles}
    limits = {v.name: VehicleLimits(max_speed_m_s=v.speed_m_s, max_yaw_rate_rad_s=v.max_yaw_rate_rad_s,
                                    max_accel_m_s2=v.max_accel_m_s2) for v in vehicles}
    states: dict[str, KinematicState] = {}
    for v in vehicles:
        h = v.initial_heading_rad
        # Already at cruise speed on the initial heading: the paper's UAVs depart at constant v.
        states[v.name] = KinematicState(north_m=v.start_enu_m[1], east_m=v.start_enu_m[0],
                                        down_m=-v.cruise_alt_m, vn_m_s=v.speed_m_s * math.sin(h),
                                        ve_m_s=v.speed_m_s * math.cos(h),
                                        yaw_rad=enu_heading_to_ned_yaw(h))
    field = ObstacleField.from_world(mission.world)
    truth = TruthGeometry(mission.world)
    dt = mission.planner.dt_s
    n_ticks = int(math.floor(mission.safety.time_limit_s / dt + 1e-9))
    t_log = {v.name: [0.0] for v in vehicles}
    x_log = {v.name: [states[v.name].east_m] for v in vehicles}
    y_log = {v.name: [states[v.name].north_m] for v in vehicles}
    ticks: dict[str, list[TickResult]] = {v.name: [] for v in vehicles}
    active = [v.name for v in vehicles]

    for k in range(n_ticks):
        t = k * dt
        snapshot = field.at_time(t)
        commands = {}
        for name in list(active):
            others = [states[n] for n in states if n != name]
            own = states[name]
            nearest = min(others, key=lambda s: (s.east_m - own.east_m) ** 2 + (s.north_m - own.north_m) ** 2,
                          default=None)
            result = planners[name].tick(_pose(own), None if nearest is None else _other(nearest), snapshot, t)
            ticks[name].append(result)
            if result.arrived:
                active.remove(name)
            else:
                commands[name] = (HOVER if result.command is None
                                  else body_command(result.yaw_rate_rad_s, result.speed_m_s))
        if not active:
            break
        before = {n: states[n] for n in states}
        for name, command in commands.items():
            states[name] = step(states[name], command, limits[name], dt)
            t_log[name].append(t + dt)
            x_log[name].append(states[name].east_m)
            y_log[name].append(states[name].north_m)
        if _violation(mission, truth, before, states, active, t, t + dt):
            break

    tracks = {n: Track(np.array(t_log[n]), np.array(x_log[n]), np.array(y_log[n])) for n in t_log}
    planner_ms = {n: [r.planner_ms for r in ticks[n] if not r.arrived] for n in ticks}
    summary = summarize(mission, tracks, routes=routes, planner_ms=planner_ms, geometry=truth)
    return RunResult(mission, variant, dict(routes), tracks, ticks, summary, time.perf_counter() - started)


def _violation(mission: Mission, truth: TruthGeometry, before: dict[str, KinematicState],
               after: dict[str, KinematicState], moving: list[str], t0: float, t1: float) -> bool:
    """Did this step break a safety rule? (metrics.summarize then names it from the tracks.)"""
    if not moving:
        return False
    b = [before[n] for n in moving]
    a = [after[n] for n in moving]
    x0 = np.array([s.east_m for s in b])
    y0 = np.array([s.north_m for s in b])
    x1 = np.array([s.east_m for s in a])
    y1 = np.array([s.north_m for s in a])
    if truth.circles or truth.polygons:
        if np.any(truth.segment_clearance_m(x0, y0, x1, y1, np.full_like(x0, t0), np.full_like(x0, t1)) <= 0.0):
            return True
    if not np.all(inside_fence(mission.world, x1, y1)):
        return True
    names = list(after)
    for i, p in enumerate(names):
        for q in names[i + 1:]:
            d = pair_min_distance(before[p].east_m, before[p].north_m, after[p].east_m, after[p].north_m,
                                  before[q].east_m, before[q].north_m, after[q].east_m, after[q].north_m)
            if float(d) < mission.safety.min_separation_m:
                return True
    return False
