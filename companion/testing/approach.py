"""How a vehicle flew its final approach: did it arrive, or circle its station?

    a = station_approach(track, goal_xy, region_m=60.0, radius_m=20.0)
    a.circling          # course turned a full circle, or flew twice the straight way, in the region

The region is the disc of ``region_m`` around the station; the approach runs from the track's
first entry into it to its arrival (first sample within ``radius_m``), or to the track's end.
Path and course are measured between samples at least ``min_step_m`` apart, so that a hover's
position noise counts as neither. On PX4 (../shared/px4-sih/README.md) vehicle a
circled station B at 23-52 m for 500 s (run px4_4x_run2): many full turns inside a 60 m region.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.planning.metrics import Track

FULL_TURN_DEG = 360.0
PATH_FACTOR = 2.0  # a path inside the region longer than this x the straight way is circling too


@dataclass(frozen=True)
class Approach:
    entered: bool  # the track came within region_m of the station at all
    arrived: bool
    path_m: float  # flown inside the region, from the first entry to arrival (or the track's end)
    straight_m: float  # the straight way from the region's edge to the arrival circle
    turned_deg: float  # the course's total turning (sum of |changes|) over the same stretch
    duration_s: float

    @property
    def circling(self) -> bool:
        return self.entered and (self.turned_deg >= FULL_TURN_DEG or self.path_m > PATH_FACTOR * self.straight_m)

    def describe(self) -> str:
        how = "circling" if self.circling else "straight in"
        return (f"{how}: {self.path_m:.0f} m flown in the region for {self.straight_m:.0f} m straight, course turned "
                f"{self.turned_deg:.0f} deg in {self.duration_s:.1f} s, {'arrived' if self.arrived else 'NOT arrived'}")


def station_approach(track: Track, goal_xy: tuple[float, float], region_m: float, radius_m: float,
                     min_step_m: float = 2.0) -> Approach:
    """The approach of ``track`` to ``goal_xy`` (see the module doc)."""
    d = np.hypot(track.x_m - goal_xy[0], track.y_m - goal_xy[1])
    inside = np.flatnonzero(d <= region_m)
    straight = max(region_m - radius_m, 0.0)
    if inside.size == 0:
        return Approach(False, False, 0.0, straight, 0.0, 0.0)
    first = int(inside[0])
    hits = np.flatnonzero(d[first:] <= radius_m)
    last = first + int(hits[0]) if hits.size else len(d) - 1
    x, y = _marks(track.x_m[first:last + 1], track.y_m[first:last + 1], min_step_m)
    steps = np.hypot(np.diff(x), np.diff(y))
    course = np.arctan2(np.diff(y), np.diff(x))
    turns = np.angle(np.exp(1j * np.diff(course))) if course.size > 1 else np.zeros(0)
    return Approach(True, bool(hits.size), float(steps.sum()), straight, float(np.degrees(np.abs(turns).sum())),
                    float(track.t_s[last] - track.t_s[first]))


def _marks(x: np.ndarray, y: np.ndarray, min_step_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The samples each at least ``min_step_m`` from the one kept before (and the last): a
    hover's jitter, however long, adds neither path nor turning."""
    keep = [0]
    for i in range(1, len(x)):
        if math.hypot(x[i] - x[keep[-1]], y[i] - y[keep[-1]]) >= min_step_m:
            keep.append(i)
    if keep[-1] != len(x) - 1:
        keep.append(len(x) - 1)
    return x[keep], y[keep]


def default_region_m(turn_radius_m: float, radius_m: float) -> float:
    """One turning diameter beyond the arrival circle (80 m on small_reference): room for the last
    turn onto the station, not for an orbit round it."""
    return radius_m + 2.0 * turn_radius_m if math.isfinite(turn_radius_m) else 3.0 * radius_m
