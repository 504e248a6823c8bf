"""A*-BDWA fusion (paper section V): global nodes become BDWA's successive local goals.

This is the per-tick code that the headless runner and the live companion both call:

    planner = VehiclePlanner.build(mission, vehicle, route, variant)
    field = ObstacleField.from_world(mission.world)       # static geometry, prepared once
    snapshot = field.at_time(t_s)                         # headless: true state, now
    snapshot = field.from_tracks(adsb_tracks)             # live: what ADSB says, now
    result = planner.tick(own_pose, other_uav, snapshot, t_s)

Either way the snapshot holds the obstacles' *current* position and velocity, and BDWA predicts
them at constant velocity, so the live and headless planners see exactly the same thing.
"""

from __future__ import annotations

import bisect
import dataclasses
import math
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from companion.planning.dwa import (Command, DwaConfig, LocalGoals, NoLegalRollout, ObstacleSnapshot,
                                    OtherUav, Pose, plan_step)
from companion.planning.dwa.snapshot import assemble
from companion.planning.errors import BudgetExceeded, NoPath
from companion.planning.grid import rasterise
from companion.planning.routes import detour_route
from uav_model.world import Obstacle, World

if TYPE_CHECKING:
    from uav_model.mission import Mission, VehicleSpec
    from companion.planning.routes import Route

# Variant -> (local goals come from, sightline term on). SPEC §1's ablation table.
VARIANT_GOALS: dict[str, tuple[str, bool]] = {
    "astar-bdwa": ("sparse", True),
    "astar-bdwa-nosparse": ("raw", True),
    "bdwa": ("station", True),
    "dwa": ("station", False),
}


def variant_needs_route(variant: str) -> bool:
    return VARIANT_GOALS[variant][0] != "station"


class ObstacleTrack(NamedTuple):
    """A moving obstacle as a sensor reports it (e.g. one ADSB_VEHICLE): centre and velocity."""

    id: str
    x_m: float
    y_m: float
    vx_m_s: float
    vy_m_s: float


@dataclass(frozen=True, eq=False)
class ObstacleField:
    """The world's obstacles prepared once as arrays; makes a snapshot per tick cheaply.

    Static obstacles are fixed. Moving ones keep their shape, which a track places at its
    reported centre. A track whose id the mission does not know is an unknown intruder: it is
    avoided as a disc of ``unknown_radius_m`` (true size, plus the mission's inflation ratio).
    """

    static: ObstacleSnapshot
    moving: dict[str, Obstacle] = field(repr=False)
    inflation_ratio: float
    unknown_radius_m: float

    @classmethod
    def from_world(cls, world: World, *, inflation_ratio: float | None = None,
                   unknown_radius_m: float = 150.0) -> "ObstacleField":
        circles: list = []
        polygons: list = []
        for o in world.static_obstacles:
            _shape_rows(o, o.center, (0.0, 0.0), circles, polygons)
        if inflation_ratio is None:  # the ratio every obstacle of the mission was built with
            ratios = [o.margin_m / o.size_m for o in world.obstacles if o.size_m > 0]
            inflation_ratio = ratios[0] if ratios else 0.2
        return cls(ObstacleSnapshot.build(circles, polygons), {o.id: o for o in world.moving_obstacles},
                   inflation_ratio, unknown_radius_m)

    def from_tracks(self, tracks: Iterable[ObstacleTrack | tuple]) -> ObstacleSnapshot:
        """Snapshot from the static world plus moving obstacles' (id, x, y, vx, vy) now."""
        circles: list = []
        polygons: list = []
        for track in tracks:
            oid, x, y, vx, vy = track
            shape = self.moving.get(oid)
            if shape is None:
                r = self.unknown_radius_m
                circles.append((oid, float(x), float(y), r, r * self.inflation_ratio, float(vx), float(vy)))
            else:
                _shape_rows(shape, (float(x), float(y)), (float(vx), float(vy)), circles, polygons)
        if not circles and not polygons:
            return self.static
        return self.static.merged(ObstacleSnapshot.build(circles, polygons))

    def tracks_at(self, t_s: float) -> list[ObstacleTrack]:
        """The true state of every moving obstacle at ``t_s`` (what a perfect ADSB would say)."""
        out = []
        for o in self.moving.values():
            x, y = o.center_at(t_s)
            vx, vy = o.motion.velocity_at(t_s)
            out.append(ObstacleTrack(o.id, x, y, vx, vy))
        return out

    def at_time(self, t_s: float) -> ObstacleSnapshot:
        """Headless snapshot: moving obstacles' true position and velocity at ``t_s``."""
        return self.from_tracks(self.tracks_at(t_s))

    def at_times(self, times_s: np.ndarray) -> Iterator[ObstacleSnapshot]:
        """``at_time(t)`` for every t of ``times_s``, made cheaply: the headless runner knows
        every tick time up front. Every snapshot is a template (static + moving obstacles at
        their reference position, built once) with only the moving rows changed: their
        positions for all times come from one vectorised ``offset_at`` call per obstacle, added
        to the template in bulk, and each snapshot views its row of those arrays."""
        times = np.asarray(times_s, dtype=float)
        moving = list(self.moving.values())
        if not moving:
            yield from (self.static for _ in times)
            return
        template = self.from_tracks([ObstacleTrack(o.id, o.center[0], o.center[1], 0.0, 0.0) for o in moving])
        n_sc, n_sp = len(self.static.circle_ids), len(self.static.poly_ids)
        n_c = len(template.circle_ids)
        rows = []  # (obstacle, is circle, row in its kind's arrays, row among all obstacles)
        k_c = k_p = 0
        for o in moving:
            row = n_sc + k_c if o.is_circle else n_sp + k_p
            rows.append((o, o.is_circle, row, row if o.is_circle else n_c + row))
            k_c, k_p = k_c + o.is_circle, k_p + (not o.is_circle)
        placed = ("circle_xy_m", "bound_xy_m") + (("poly_a_m", "poly_b_m", "poly_centre_m") if k_p else ())
        bulk = {name: np.repeat(getattr(template, name)[None], len(times), axis=0) for name in placed}
        for o, circle, row, bound in rows:
            off = o.offset_at(times)  # (T, 2)
            bulk["bound_xy_m"][:, bound] += off
            if circle:
                bulk["circle_xy_m"][:, row] += off
            else:
                bulk["poly_a_m"][:, row] += off[:, None, :]
                bulk["poly_b_m"][:, row] += off[:, None, :]
                bulk["poly_centre_m"][:, row] += off
        fields = {name: getattr(template, name) for name in _SNAPSHOT_FIELDS}
        moving_rows = np.zeros(template.count, dtype=bool)  # circles, then polygons
        for _, _, _, bound in rows:
            moving_rows[bound] = True
        moved = placed + ("circle_vel_m_s", "speed_m_s") + (("poly_vel_m_s",) if k_p else ())
        shared = (moving_rows, frozenset(moved), {})  # every snapshot below differs from the template only here
        for k in range(len(times)):
            t = float(times[k])
            values = dict(fields, _subsets={}, _shared=shared)
            for name in placed:
                values[name] = bulk[name][k]
            circle_vel = values["circle_vel_m_s"] = fields["circle_vel_m_s"].copy()
            speed = values["speed_m_s"] = fields["speed_m_s"].copy()
            if k_p:
                poly_vel = values["poly_vel_m_s"] = fields["poly_vel_m_s"].copy()
            for o, circle, row, bound in rows:
                vx, vy = o.motion.velocity_at(t)
                speed[bound] = math.hypot(vx, vy)
                if circle:
                    circle_vel[row] = (vx, vy)
                else:
                    poly_vel[row] = (vx, vy)
            if k_p:
                values["polygons_move"] = bool(np.any(poly_vel))
            yield assemble(values)


def _shape_rows(o: Obstacle, centre: tuple[float, float], vel: tuple[float, float],
                circles: list, polygons: list) -> None:
    """Append ``o`` placed with its reference centre at ``centre`` to the snapshot rows."""
    if o.is_circle:
        circles.append((o.id, centre[0], centre[1], o.size_m, o.margin_m, vel[0], vel[1]))
    else:
        shift = np.array([centre[0] - o.center[0], centre[1] - o.center[1]])
        polygons.append((o.id, o.vertices() + shift, o.margin_m, vel[0], vel[1]))


def snapshot_from_tracks(world: World, tracks: Iterable[ObstacleTrack | tuple]) -> ObstacleSnapshot:
    """One-off snapshot from the static world and tracks; keep an ObstacleField when ticking."""
    return ObstacleField.from_world(world).from_tracks(tracks)


def snapshot_at(world: World, t_s: float) -> ObstacleSnapshot:
    """One-off headless snapshot at ``t_s``; keep an ObstacleField when ticking."""
    return ObstacleField.from_world(world).at_time(t_s)


# Every ObstacleSnapshot field, derived ones included (what assemble needs).
_SNAPSHOT_FIELDS = tuple(f.name for f in dataclasses.fields(ObstacleSnapshot))


class LocalGoalTracker:
    """Walks a node list: the current local goal advances when the vehicle is inside the
    acceptance radius of it, or has passed it (its projection on the segment from the previous
    node lies beyond the node). The last node, the station, is never passed over.

    Mutable by design: it is the one piece of per-vehicle planning state that persists across
    ticks. ``index`` is the current goal's position in ``nodes``.
    """

    def __init__(self, nodes: np.ndarray, acceptance_radius_m: float):
        nodes = np.asarray(nodes, dtype=float)
        if nodes.ndim != 2 or nodes.shape[1] != 2 or len(nodes) < 2:
            raise ValueError("a tracker needs at least two nodes (start and station), shape (N, 2)")
        self.nodes = nodes
        self.acceptance_radius_m = float(acceptance_radius_m)
        self.index = 1
        self._along_m = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(nodes, axis=0).T))])
        self._along = self._along_m.tolist()  # plain floats: window() runs every tick
        self._xy = [(float(x), float(y)) for x, y in nodes]
        self._windows: dict[tuple, LocalGoals] = {}

    @property
    def goal_xy(self) -> tuple[float, float]:
        return self._xy[self.index]

    @property
    def is_last(self) -> bool:
        return self.index == len(self.nodes) - 1

    def window(self, x_m: float, y_m: float, reach_m: float, station_radius_m: float) -> LocalGoals:
        """The current goal and every node after it that a rollout of length ``reach_m`` from
        (x, y) could make the target (it must reach the node before it first)."""
        i = self.index
        gx, gy = self._xy[i]
        # path length from (x, y) to each remaining node, via the current goal: within reach?
        to_goal = math.hypot(gx - x_m, gy - y_m)
        count = min(len(self._xy) - i, bisect.bisect_right(self._along, reach_m - to_goal + self._along[i], lo=i) - i + 1)
        key = (i, count, station_radius_m)
        goals = self._windows.get(key)
        if goals is None:  # a few distinct windows per flight: built once each
            goals = self._windows[key] = LocalGoals(
                self.nodes[i:i + count], self._xy[i - 1], self.acceptance_radius_m, station_radius_m,
                ends_at_station=i + count == len(self._xy))
        return goals

    def remaining_m(self, x_m: float, y_m: float) -> float:
        """Route length left from (x, y): to the current goal, then along the nodes after it."""
        gx, gy = self._xy[self.index]
        return math.hypot(gx - x_m, gy - y_m) + self._along[-1] - self._along[self.index]

    def update(self, x_m: float, y_m: float) -> tuple[float, float]:
        """Advance past every node already reached or passed; return the current goal."""
        while not self.is_last:
            gx, gy = self._xy[self.index]
            px, py = self._xy[self.index - 1]
            reached = math.hypot(x_m - gx, y_m - gy) <= self.acceptance_radius_m
            passed = (x_m - gx) * (gx - px) + (y_m - gy) * (gy - py) > 0.0
            if not (reached or passed):
                break
            self.index += 1
        return self.goal_xy


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


_PROGRESS_M = 20.0  # the remaining route must shorten by more than this to count as progress


@dataclass(frozen=True)
class Replanning:
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

    Re-planning is split so that a live caller never blocks its event loop on A*: ``tick`` sets
    ``replan_due``; the caller runs :meth:`plan_detour` (pure, a few tens of ms; in a worker
    thread if it likes) and hands the result to :meth:`adopt_detour`. The headless runner does
    both at once, right after the tick that set the flag.
    """

    def __init__(self, name: str, config: DwaConfig, tracker: LocalGoalTracker, arrival_radius_m: float,
                 replanning: Replanning | None = None):
        self.name = name
        self.config = config
        self.tracker = tracker
        self.arrival_radius_m = arrival_radius_m
        self.arrived = False
        self.replanning = replanning if replanning is not None and replanning.after_s > 0 else None
        self.replan_due = False
        self.replans = 0  # how many detours were planned (adopted or not)
        self._progress: tuple[float, float] | None = None  # (best remaining route m, sim time it was reached)
        self._grid = None  # the static grid, rasterised at the first detour
        self._station_xy = (float(tracker.nodes[-1][0]), float(tracker.nodes[-1][1]))

    @classmethod
    def build(cls, mission: "Mission", vehicle: "VehicleSpec", route: "Route | None",
              variant: str | None = None, *, earlier: "Iterable[Route]" = ()) -> "VehiclePlanner":
        """The planner for ``vehicle``; ``route`` is required for the A* variants. ``earlier``:
        the routes of the vehicles above it (:func:`routes.higher_routes`), which a detour after a
        stall keeps to the priority rule first.

        Priority (paper §II.B: the UAV leaving A "is prioritized to arrive"): the first vehicle in
        priority order has right of way and flies without the sightline term; every other
        vehicle carries the sightline objective and bends its path to keep the sight line
        occluded. Separation is enforced by all of them.
        """
        variant = variant or mission.planner.variant
        goals_from, sightline = VARIANT_GOALS[variant]
        sightline = sightline and mission.by_priority[0].name != vehicle.name
        if goals_from == "station":
            nodes = np.array([vehicle.start_enu_m, vehicle.goal_enu_m], dtype=float)
        elif route is None:
            raise ValueError(f"variant {variant!r} needs an A* route for vehicle {vehicle.name!r}")
        else:
            nodes = route.sparse_enu_m if goals_from == "sparse" else route.raw_enu_m
        fence = tuple(float(v) for v in mission.world.geofence.bounds)
        config = DwaConfig.from_settings(mission.planner, vehicle, mission.safety, sightline=sightline, fence_m=fence)
        tracker = LocalGoalTracker(nodes, mission.planner.acceptance_radius_m)
        replanning = None if goals_from == "station" else Replanning(
            mission.planner.replan_after_s, mission.world, mission.planner.grid_resolution_m, goals_from == "sparse",
            tuple(earlier), mission.safety.min_separation_m)
        return cls(vehicle.name, config, tracker, mission.safety.arrival_radius_m, replanning)

    def plan_detour(self, x_m: float, y_m: float) -> np.ndarray | None:
        """A new route from (x, y) to the station, or None when there is none. Reads only what
        does not change while flying (and caches the grid), so it may run in a worker thread."""
        if self.replanning is None:
            return None
        r = self.replanning
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
        self.replan_due = False
        self.replans += 1
        adopted = nodes is not None and len(nodes) >= 2
        if adopted:
            self.tracker = LocalGoalTracker(nodes, self.tracker.acceptance_radius_m)
        self._progress = (self.tracker.remaining_m(x_m, y_m), t_s)
        return adopted

    def _watch_progress(self, x_m: float, y_m: float, t_s: float) -> None:
        remaining = self.tracker.remaining_m(x_m, y_m)
        if self._progress is None or remaining < self._progress[0] - _PROGRESS_M:
            self._progress = (remaining, t_s)
        elif t_s - self._progress[1] >= self.replanning.after_s:
            self.replan_due = True

    @property
    def station_xy(self) -> tuple[float, float]:
        return self._station_xy

    def tick(self, own: Pose, other: OtherUav | None, snapshot: ObstacleSnapshot, t_s: float) -> TickResult:
        """Decide this tick's command from the current own pose, other UAV and obstacles.

        Once inside the arrival radius the vehicle has arrived for good and holds.
        """
        started = time.perf_counter()
        sx, sy = self.station_xy
        if self.arrived or math.hypot(own.x_m - sx, own.y_m - sy) <= self.arrival_radius_m:
            self.arrived = True
            return TickResult(t_s, None, (sx, sy), self.tracker.index, True,
                              (time.perf_counter() - started) * 1e3, "arrived")
        goal = self.tracker.update(own.x_m, own.y_m)
        if self.replanning is not None and not self.replan_due:
            self._watch_progress(own.x_m, own.y_m, t_s)
        reach = self.config.reach_m + self.tracker.acceptance_radius_m
        goals = self.tracker.window(own.x_m, own.y_m, reach, self.arrival_radius_m)
        decision = plan_step(own, goals, other, snapshot, self.config)
        ms = (time.perf_counter() - started) * 1e3
        if isinstance(decision, NoLegalRollout):
            if decision.recovery is not None:
                return TickResult(t_s, decision.recovery, goal, self.tracker.index, False, ms,
                                  recovery_reason=decision.reason)
            if decision.escape is not None:
                return TickResult(t_s, decision.escape, goal, self.tracker.index, False, ms, None, decision.reason)
            return TickResult(t_s, None, goal, self.tracker.index, False, ms, decision.reason)
        return TickResult(t_s, decision, goal, self.tracker.index, False, ms)
