"""TEMPORARY SHIM (local-planning engineer): stands in for bounds.py until it lands; delete then.

Single-disk tangent + arc + tangent bound (SPEC §1), else the straight-line distance.
"""
from __future__ import annotations

import math

import numpy as np
from shapely.geometry import LineString, Point


def lower_bound_m(world, start, goal):
    circles = [o for o in world.static_obstacles if o.is_circle]
    a = np.asarray(start, dtype=float)
    b = np.asarray(goal, dtype=float)
    if len(circles) != 1:
        return float(np.hypot(*(b - a)))
    o = circles[0]
    r = o.inflated_radius_m
    c = np.asarray(o.center)
    if LineString([start, goal]).distance(Point(c)) >= r:
        return float(np.hypot(*(b - a)))
    da = float(np.hypot(*(a - c)))
    db = float(np.hypot(*(b - c)))
    th = math.acos(float(np.dot(a - c, b - c)) / da / db)
    return math.sqrt(da**2 - r**2) + math.sqrt(db**2 - r**2) + r * (th - math.acos(r / da) - math.acos(r / db))


def lower_bound_s(world, start, goal, speed):
    return lower_bound_m(world, start, goal) / speed
