"""The occlusion certificate, decided the slow and obvious way (for tests only).

Same discrete model as companion.planning.coordination.search (mission grid cells, the lower vehicle's
step from ``step_model``, the higher vehicle forecast along its route after a hold), but none of
its machinery: Python sets of (cell, step) states, neighbours found by walking the sub-steps cell
by cell, the sight line tested with plain shapely per state, every hold tried in turn, and for
the closest approach every candidate distance D tried in turn:

    a path has its closest approach blocked  <=>  for some D, every open state on it is farther
    than D and some blocked state on it is within D.

Distances are compared squared, and the higher vehicle's positions are those of the model (to
the micrometre, as ``SpaceTimeProblem.positions``): a forecast at (13, 40) computed as
(12.999999999999998, 40) once made an open state 1e-14 m farther than a blocked one at the same
true distance, and this check called feasible what the model's tie forbids.
"""

from __future__ import annotations

import math
from functools import lru_cache

from shapely.geometry import LineString, Point

from uav_model.mission import Mission
from companion.planning.grid import rasterise
from companion.planning.coordination.spacetime import step_model
from companion.planning.coordination.timed import forecast

_STEPS_4 = ((1, 0), (-1, 0), (0, 1), (0, -1))
_STEPS_8 = _STEPS_4 + ((1, 1), (1, -1), (-1, 1), (-1, -1))


class BruteForce:
    def __init__(self, mission: Mission, routes: dict):
        self.mission = mission
        self.higher, self.lower = mission.by_priority[0], mission.by_priority[1]
        self.route = routes[self.higher.name].sparse_enu_m
        self.grid = rasterise(mission.world, mission.planner.grid_resolution_m)
        self.model = step_model(self.grid.resolution_m, self.lower.speed_m_s, mission.coordination.step_s,
                                mission.safety.min_separation_m, self.higher.speed_m_s)
        self.horizon = max(1, int(mission.safety.time_limit_s // self.model.step_s))
        self.start = self._cell(self.lower.start_enu_m)
        self.goal = self._cell(self.lower.goal_enu_m)
        ny, nx = self.grid.shape
        self.free = {(x, y) for x in range(nx) for y in range(ny) if not self.grid.occupied[y, x]}
        self.free |= {self.start, self.goal}
        self.next = lru_cache(maxsize=None)(self._next)
        self.sight_blocked = lru_cache(maxsize=None)(self._sight_blocked)
        self.higher_at = lru_cache(maxsize=None)(self._higher_at)

    def _higher_at(self, k: int, hold_s: float) -> tuple[float, float]:
        xy = forecast(self.higher.name, self.route, self.higher.speed_m_s, hold_s).planned_position_at(
            k * self.model.step_s)
        return round(float(xy[0]), 6), round(float(xy[1]), 6)

    def _cell(self, xy) -> tuple[int, int]:
        ny, nx = self.grid.shape
        ix, iy = self.grid.world_to_cell(*xy)
        return min(max(ix, 0), nx - 1), min(max(iy, 0), ny - 1)

    def _next(self, cell: tuple[int, int]) -> frozenset:
        """Cells reachable in one step: the sub-steps walked one cell at a time (or not at all)."""
        reach = {cell}
        for kind in self.model.moves:
            steps = _STEPS_8 if kind == 8 else _STEPS_4
            reach |= {(x + dx, y + dy) for x, y in reach for dx, dy in steps if (x + dx, y + dy) in self.free}
        return frozenset(reach)

    def _sight_blocked(self, cell: tuple[int, int], p: tuple[float, float]) -> bool:
        q = self.grid.cell_to_world(*cell)
        seg = Point(q) if q == p else LineString([q, p])
        for o in self.mission.world.static_obstacles:
            if o.is_circle:
                if seg.distance(Point(o.center)) < o.size_m:
                    return True
            elif seg.intersects(o.footprint):
                return True
        return False

    def _state(self, cell, k, hold_s):
        """(allowed by separation, sight blocked, squared distance) of the lower vehicle at cell, step k."""
        p = self.higher_at(k, hold_s)
        q = self.grid.cell_to_world(*cell)
        d2 = (q[0] - p[0]) ** 2 + (q[1] - p[1]) ** 2
        return d2 >= self.model.min_distance_m ** 2, self.sight_blocked(cell, p), d2

    def _reaches_goal(self, hold_s: float, ok) -> bool:
        """Breadth-first over (cell, step, flag) states; ``ok(cell, k)`` -> None (forbidden) or
        whether the state raises the flag. Success: the goal at the horizon with the flag up."""
        first = ok(self.start, 0)
        if first is None:
            return False
        layer = {(self.start, first)}
        for k in range(1, self.horizon + 1):
            nxt = set()
            for cell, flag in layer:
                for c in self.next(cell):
                    f = ok(c, k)
                    if f is not None:
                        nxt.add((c, flag or f))
            layer = nxt
        return (self.goal, True) in layer

    def whole_flight(self, hold_s: float) -> bool:
        states = {}

        def ok(cell, k):
            key = (cell, k)
            if key not in states:
                states[key] = self._state(cell, k, hold_s)
            far, blocked, _ = states[key]
            return True if far and blocked else None
        return self._reaches_goal(hold_s, ok)

    def closest_approach(self, hold_s: float) -> bool:
        table = {(c, k): self._state(c, k, hold_s) for c in self.free for k in range(self.horizon + 1)}
        # Only a blocked state on some separated path can be a closest approach: D runs over those.
        on_path = self._on_separated_paths(table)
        candidates = sorted({table[s][2] for s in on_path if table[s][1]})
        for near2 in candidates:
            def ok(cell, k, near2=near2):
                far, blocked, d2 = table[(cell, k)]
                if not far or (not blocked and d2 <= near2):
                    return None
                return blocked and d2 <= near2
            if self._reaches_goal(hold_s, ok):
                return True
        return False

    def earliest_near(self, hold_s: float, near_m: float, margin_m: float) -> int | None:
        """The earliest step at which a path reaches the goal (and may park there to the
        horizon) with no open state within ``near_m + margin_m`` and a blocked one within
        ``near_m`` (:func:`companion.planning.coordination.nearpath.earliest_near`); None: no such path."""
        near2 = near_m ** 2  # the thresholds squared as the model squares them
        far2 = (math.sqrt(near2) + margin_m) ** 2 if margin_m else near2

        def ok(cell, k):
            far, blocked, d2 = self._state(cell, k, hold_s)
            if not far or (not blocked and d2 <= far2):
                return None
            return blocked and d2 <= near2
        parked = [ok(self.goal, k) is not None for k in range(self.horizon + 1)]
        first = ok(self.start, 0)
        layer = set() if first is None else {(self.start, first)}
        for k in range(self.horizon + 1):
            if k:
                layer = {(c, flag or f) for cell, flag in layer for c in self.next(cell)
                         for f in [ok(c, k)] if f is not None}
            if (self.goal, True) in layer and all(parked[k:]):
                return k
        return None

    def _on_separated_paths(self, table) -> set:
        """States (cell, k) on some start-to-goal path that keeps only the separation."""
        fwd = [{self.start} if table[(self.start, 0)][0] else set()]
        for k in range(1, self.horizon + 1):
            fwd.append({c for cell in fwd[-1] for c in self.next(cell) if table[(c, k)][0]})
        back = {self.goal} & fwd[-1]
        states = {(c, self.horizon) for c in back}
        for k in range(self.horizon - 1, -1, -1):
            back = {c for c in fwd[k] if self.next(c) & back}
            states |= {(c, k) for c in back}
        return states

    def least_hold(self, check, max_hold_s: float) -> float | None:
        for i in range(math.floor(max_hold_s / self.model.step_s + 1e-9) + 1):
            if check(i * self.model.step_s):
                return i * self.model.step_s
        return None
