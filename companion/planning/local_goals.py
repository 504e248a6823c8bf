"""Fusion (paper section V): the global route's nodes become BDWA's successive local goals."""

from __future__ import annotations

import bisect
import math

import numpy as np

from companion.planning.dwa import LocalGoals


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
            goals = self._windows[key] = LocalGoals.along(self.nodes, i, count, self.acceptance_radius_m,
                                                          station_radius_m)
        return goals

    def remaining_m(self, x_m: float, y_m: float) -> float:
        """Route length left from (x, y): to the current goal, then along the nodes after it."""
        gx, gy = self._xy[self.index]
        return math.hypot(gx - x_m, gy - y_m) + self._along[-1] - self._along[self.index]

    def advance_to(self, along_m: float) -> tuple[float, float]:
        """Advance past every node no farther along the nodes than ``along_m`` (a vehicle known
        to be that far along them: :meth:`timed.TimedRoute.progress_at`); return the current goal."""
        while not self.is_last and self._along[self.index] <= along_m:
            self.index += 1
        return self.goal_xy

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
