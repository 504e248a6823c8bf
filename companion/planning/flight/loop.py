"""The headless flight loop: every vehicle flown by its VehiclePlanner on the shared plant.

No sockets and no clocks: the same per-tick planner code the live companion runs
(:class:`VehiclePlanner.tick` on an :class:`ObstacleSnapshot` of the obstacles' state *now*),
the same plant as the SITL stub (the mission's :class:`uav_model.plant.Plant`, fed a BODY_NED
velocity and a PX4 yawspeed converted by :mod:`uav_model.frames`), and the same scoring as every other flight
(:func:`companion.planning.metrics.summarize`).

The loop ticks at the planner's dt. All vehicles decide from the state at t, then all step.
A vehicle inside its arrival radius has arrived: it is frozen there and its track ends. A
vehicle whose planner finds no legal rollout yaws in place toward a heading that has one (BODY
velocity 0 + yawspeed: the plant brakes within its acceleration limit while it yaws), hovers that
tick, or flies the escape the planner offers. The run stops at the first
collision (checked along each step's segment against the true footprints, moving ones where
they really are), separation or geofence violation, when everyone has arrived, or at the time
limit.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from uav_model.frames import enu_heading_to_ned_yaw, enu_to_ned, enu_yaw_rate_to_ned, ned_to_enu
from uav_model.mission import Mission
from companion.planning.budget import Budget, spend
from companion.planning.dwa import OtherUav
from companion.planning.fleet import FleetView
from companion.planning.flight.replay import SoloFlight, SoloRecorder, decide, pose_of
from companion.planning.obstacle_field import ObstacleField
from companion.planning.vehicle_planner import TickResult
from companion.planning.metrics import (PlannerCounts, RunSummary, ScheduleRecord, Track, TruthGeometry,
                                        inside_fence, pair_min_distance, summarize)
from companion.planning.routes import Route
from uav_model.plant import (HOVER, KinematicState, PlantLimits, VelocityCommand, VelocityFrame, initial_state,
                             limits_for, step_for)

if TYPE_CHECKING:
    from companion.planning.flight.fleet_setup import FleetSetup


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
    solo: SoloFlight | None = None  # the flight of the vehicle recorded (fly's ``record``)

    @property
    def success(self) -> bool:
        return self.summary.success

    @property
    def speed_factor(self) -> float:
        """Simulated seconds per wall-clock second."""
        return self.summary.duration_s / self.wall_s if self.wall_s > 0 else math.inf


_CHECK_EVERY_TICKS = 32  # safety is checked in vectorised batches; a violation truncates the run there


def body_command(yaw_rate_enu_rad_s: float, speed_m_s: float) -> VelocityCommand:
    """The planner's (ENU yaw rate, forward speed) as PX4's BODY_NED setpoint."""
    return VelocityCommand(VelocityFrame.BODY_NED, speed_m_s, 0.0, 0.0,
                           enu_yaw_rate_to_ned(yaw_rate_enu_rad_s))


def _xy(s: KinematicState) -> tuple[float, float]:
    x, y, _ = ned_to_enu(s.north_m, s.east_m)
    return x, y


def _other(s: KinematicState, xy: tuple[float, float], parked: bool = False) -> OtherUav:
    """The vehicle in state ``s`` at ``xy`` (its :func:`_xy`) as another vehicle sees it."""
    if parked:
        return OtherUav(*xy, 0.0, 0.0, arrived=True)
    vx, vy, _ = ned_to_enu(s.vn_m_s, s.ve_m_s)
    return OtherUav(*xy, vx, vy)


def start_states(mission: Mission) -> tuple[dict[str, PlantLimits], dict[str, KinematicState]]:
    """Each vehicle's plant limits and its state at t = 0, at its start station."""
    limits = {v.name: limits_for(mission.plant, speed_m_s=v.speed_m_s, max_yaw_rate_rad_s=v.max_yaw_rate_rad_s,
                                 max_accel_m_s2=v.max_accel_m_s2) for v in mission.vehicles}
    states: dict[str, KinematicState] = {}
    for v in mission.by_priority:
        h = v.spawn_heading_rad
        # Already at cruise speed on the initial heading: the paper's UAVs depart at constant v.
        north, east, down = enu_to_ned(v.start_enu_m[0], v.start_enu_m[1], v.cruise_alt_m)
        vn, ve, _ = enu_to_ned(v.speed_m_s * math.cos(h), v.speed_m_s * math.sin(h))
        states[v.name] = initial_state(mission.plant, KinematicState(
            north_m=north, east_m=east, down_m=down, vn_m_s=vn, ve_m_s=ve, yaw_rad=enu_heading_to_ned_yaw(h)),
            limits[v.name])
    return limits, states


def fly(mission: Mission, fleet: FleetSetup, routes: dict[str, Route], *,
        lower_bounds_s: dict[str, float | None] | None = None, budget: Budget | None = None,
        started: float | None = None, record: str | None = None) -> RunResult:
    """Fly ``mission`` (its variant set) headless with ``fleet`` (:func:`fleet_setup.build_fleet`)
    and score it; ``routes`` are reported with the result, ``lower_bounds_s`` as for
    :func:`metrics.summarize`; ``started``: the ``time.perf_counter()`` the run's wall time counts
    from (default: now). ``record``: a vehicle whose flight, tick by tick, the result keeps
    (:attr:`RunResult.solo`). The first vehicle replays ``fleet.solo`` (its flight alone, when it
    flies alike: :mod:`replay`) while nobody is within its separation reach. Raises
    :class:`companion.planning.budget.BudgetSpent` when ``budget`` (a unit per tick) runs out."""
    started = time.perf_counter() if started is None else started
    variant = mission.planner.variant
    vehicles = mission.by_priority
    planners, clocks = fleet.planners, fleet.clocks
    step = step_for(mission.plant)
    limits, states = start_states(mission)
    field = ObstacleField.from_world(mission.world)
    truth = TruthGeometry(mission.world)
    dt = mission.planner.dt_s
    n_ticks = int(math.floor(mission.safety.time_limit_s / dt + 1e-9))
    names = [v.name for v in vehicles]
    rank = {n: i for i, n in enumerate(names)}
    hides = [mission.hides_from(n) for n in names]  # assigned sight-line partners (None: the nearest above)
    reach = [planners[n].separation_reach for n in names]
    # rows[i] = every vehicle's (x, y) at t = i * dt; an arrived vehicle repeats its last row.
    rows = [[_xy(states[n]) for n in names]]
    last_row = {n: None for n in names}  # the row of arrival
    ticks: dict[str, list[TickResult]] = {n: [] for n in names}
    active = list(names)
    watch = SafetyWatch(mission, truth, dt)
    bad = None
    top = names[0]
    solo = fleet.solo if len(names) > 1 and fleet.solo is not None and \
        fleet.solo.replays(mission, top, planners[top], dt) else None
    read_last = None  # the first vehicle's last tick, when it was read from solo
    kept = 0  # ticks of the first vehicle its planner has kept (decided, or followed from solo)
    recorder = None if record is None else SoloRecorder(mission, record, planners[record])

    def catch_up(k: int) -> None:  # the first vehicle's planner keeps what it would have by tick k
        nonlocal kept
        if solo is not None and kept < k:
            solo.catch_up(planners[top], kept, k, field, dt, clocks is not None)
        kept = k

    def stop_replay(k: int) -> None:  # the first vehicle decides again from tick k on, for good
        nonlocal solo
        catch_up(k)
        solo = None

    snapshots = field.at_times(dt * np.arange(n_ticks))
    for k in range(n_ticks):
        spend(budget)
        t = k * dt
        snapshot = next(snapshots)
        commands = {}
        here = dict(zip(names, rows[-1]))  # every vehicle's (x, y) now
        if clocks is not None:
            for name in active:
                clocks.observe(name, here[name], t)
            for name, route in clocks.update(t).items():  # a lower vehicle far behind its plan: re-planned
                if name == top:
                    stop_replay(k)
                planners[name].adopt_timed(route, clocks.sight_near_m(name))
        # Each vehicle as the others see it this tick (an arrived one parked at its station: kept
        # clear of, no longer flying anywhere), and whom each reacts to, from one distance matrix.
        view = None if len(names) == 1 else FleetView(  # flying alone (a forecast): nobody to react to
            rows[-1],
            [_other(states[n], here[n], parked=n not in active) for n in names],
            names, hides, reach)
        for name in list(active):
            own = states[name]
            planner = planners[name]
            result = None
            if name == top and solo is not None:
                if k >= len(solo.results) or not (solo.states[k] is own or solo.states[k] == own):
                    stop_replay(k)  # off its flight alone: it never gets back on it
                elif view.alone(0):
                    result, read_last = solo.results[k], k  # what it decided here alone: nobody can bind it
                else:
                    catch_up(k)  # within someone's reach, on its flight alone still: it decides
            if result is None:
                if view is None:
                    other, separate_from = None, ()
                else:
                    reaction = view.reaction(rank[name])
                    other, separate_from = reaction.other, reaction.separate_from
                result = decide(planner, pose_of(own), other, snapshot, t,
                                None if clocks is None else clocks.now(name, t), separate_from)
                if name == top:
                    kept, read_last = k + 1, None
            if recorder is not None and name == record:
                recorder.add(own)
            ticks[name].append(result)
            if result.arrived:
                active.remove(name)
                if view is not None:
                    view.park(rank[name])
                if clocks is not None:
                    clocks.done(name)
                last_row[name] = k
            else:
                commands[name] = (HOVER if result.command is None
                                  else body_command(result.yaw_rate_rad_s, result.speed_m_s))
        if not active:
            break
        for name, command in commands.items():
            if name == top and read_last == k and k + 1 < len(solo.states):
                states[name] = solo.states[k + 1]  # where the same command took it alone
            else:
                states[name] = step(states[name], command, limits[name], dt)
        rows.append([_xy(states[n]) for n in names])
        bad = watch.poll(rows)
        if bad is not None:
            break
    if bad is None:
        bad = watch.finish(rows)
    if bad is not None:  # stop at the step that broke a rule: drop what was flown after it
        del rows[bad + 2:]
        for name in names:
            del ticks[name][bad + 1:]

    tracks = tracks_from_rows(names, rows, last_row, dt)
    planner_ms = {n: [r.planner_ms for r in ticks[n] if not r.arrived] for n in ticks}
    summary = summarize(mission, tracks, routes=routes, planner_ms=planner_ms, geometry=truth,
                        lower_bounds_s=lower_bounds_s)
    summary = dataclasses.replace(summary, planner={n: PlannerCounts(  # how often the fallbacks acted
        no_rollout_ticks=sum(r.command is None and not r.arrived for r in ticks[n]),
        escape_ticks=sum(r.escape_reason is not None for r in ticks[n]),
        recovery_ticks=sum(r.recovery_reason is not None for r in ticks[n]),
        stall_detours=fleet.solo.detours[read_last] if n == top and read_last is not None else planners[n].detours,
        timed_replans=0 if clocks is None else clocks.replans.get(n, 0)) for n in names},
        schedule=ScheduleRecord(fleet.coordination.hold_s_max, fleet.coordination.forecast.value,
                                fleet.departure_hold_s))
    return RunResult(mission, variant, dict(routes), tracks, ticks, summary, time.perf_counter() - started,
                     None if recorder is None else recorder.flight(ticks[record]))


def tracks_from_rows(names: list[str], rows: list, last_row: dict[str, int | None], dt: float) -> dict[str, Track]:
    """Per-vehicle tracks from rows of every vehicle's (x, y) per tick; a track ends at its arrival row."""
    xy = np.asarray(rows)  # (T, V, 2)
    tracks = {}
    for i, name in enumerate(names):
        end = len(xy) - 1 if last_row[name] is None else min(last_row[name], len(xy) - 1)
        tracks[name] = Track(dt * np.arange(end + 1), xy[:end + 1, i, 0], xy[:end + 1, i, 1])
    return tracks


class SafetyWatch:
    """The safety rules, checked over the flown rows in batches (``first_violation``) as they grow."""

    def __init__(self, mission: Mission, truth: TruthGeometry, dt: float, every: int = _CHECK_EVERY_TICKS):
        self.mission, self.truth, self.dt, self.every = mission, truth, dt, every
        self.checked = 0  # rows[0..checked] are known to be safe

    def poll(self, rows: list, force: bool = False) -> int | None:
        """The first unsafe step once ``every`` new rows have come (or now, if forced)."""
        if not force and len(rows) - 1 - self.checked < self.every:
            return None
        bad = first_violation(self.mission, self.truth, rows, self.checked, self.dt)
        if bad is None:
            self.checked = len(rows) - 1
        return bad

    def finish(self, rows: list) -> int | None:
        """The first unsafe step among the rows not checked yet."""
        if len(rows) - 1 <= self.checked:
            return None
        return first_violation(self.mission, self.truth, rows, self.checked, self.dt)


def first_violation(mission: Mission, truth: TruthGeometry, rows: list, first: int, dt: float) -> int | None:
    """The first step i >= first (rows[i] -> rows[i + 1]) that breaks a safety rule, or None.

    Checked in batches for speed; metrics.summarize then names the rule from the tracks.
    """
    xy = np.asarray(rows[first:])  # (n + 1, V, 2)
    a, b = xy[:-1], xy[1:]
    n, nv = a.shape[0], a.shape[1]
    bad = np.zeros(n, dtype=bool)
    if truth.circles or truth.polygons:
        t0 = np.repeat(dt * np.arange(first, first + n), nv)
        clear = truth.segment_clearance_m(a[..., 0].ravel(), a[..., 1].ravel(), b[..., 0].ravel(), b[..., 1].ravel(),
                                          t0, t0 + dt, upto_m=1.0)  # only contact matters here
        bad |= (clear <= 0.0).reshape(n, nv).any(axis=1)
    bad |= ~inside_fence(mission.world, b[..., 0], b[..., 1]).all(axis=1)
    if nv > 1:  # every pair at once: (n, pairs)
        i, j = np.triu_indices(nv, 1)
        d = pair_min_distance(a[:, i, 0], a[:, i, 1], b[:, i, 0], b[:, i, 1], a[:, j, 0], a[:, j, 1], b[:, j, 0], b[:, j, 1])
        bad |= (d < mission.safety.min_separation_m).any(axis=1)
    hits = np.flatnonzero(bad)
    return first + int(hits[0]) if hits.size else None
