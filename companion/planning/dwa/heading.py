"""The heading critic H: 180 deg minus the deviation from the bearing to the local goal at the
prediction point (paper eq. 7), toward the goal the tracker would hold there."""

from __future__ import annotations

import math

import numpy as np

from companion.planning.dwa import libm
from companion.planning.dwa.types import LocalGoals


def heading_scores(pts: np.ndarray, final_heading: np.ndarray, goals: LocalGoals) -> np.ndarray:
    """H (S,) in degrees: 180 - |heading - bearing to goal| at each prediction point, toward the
    goal the tracker would hold there (see :class:`LocalGoals`). ``pts``: rollouts (S, K + 1, 2)."""
    return heading_from_ends(pts[:, -1, 0], pts[:, -1, 1], final_heading, goals, pts[0, 0], pts[..., 0], pts[..., 1])


def single_target(goals: LocalGoals, reach_m: float, origin: tuple[float, float]) -> bool:
    """Whether every rollout is scored toward the first goal, so that only the prediction points
    matter: one goal, and when it is the station, no prediction point (at most ``reach_m`` from
    ``origin``, the pose) can reach it."""
    if len(goals.nodes_xy) != 1:
        return False
    if not goals.ends_at_station:
        return True
    x0, y0 = origin
    return math.hypot(goals.first_xy[0] - x0, goals.first_xy[1] - y0) > reach_m + goals.station_radius_m


def resolve_single(ex: np.ndarray, ey: np.ndarray, goals: LocalGoals, origin: tuple[float, float],
                   single: bool | None) -> bool:
    """``single`` when the caller knows it, else :func:`single_target` for prediction points
    (ex, ey) leaving ``origin``."""
    if single is not None:
        return single
    x0, y0 = origin
    dx, dy = ex - x0, ey - y0
    return single_target(goals, math.sqrt(float((dx * dx + dy * dy).max())), origin)


def heading_toward(ex: np.ndarray, ey: np.ndarray, final_heading: np.ndarray, tx, ty) -> np.ndarray:
    """H (S,) toward the target (tx, ty) (floats, or one per rollout): 180 - |heading - bearing|
    in degrees."""
    bearing = libm.arctan2(ty - ey, tx - ex)  # the compiled kernels' bits (see libm)
    deviation = np.abs((final_heading - bearing + np.pi) % (2.0 * np.pi) - np.pi)
    return 180.0 - np.degrees(deviation)


def heading_from_ends(ex: np.ndarray, ey: np.ndarray, final_heading: np.ndarray, goals: LocalGoals,
                      origin: tuple[float, float], px: np.ndarray | None, py: np.ndarray | None,
                      single: bool | None = None, soonest_deg: float = 0.0) -> np.ndarray:
    """heading_scores from the prediction points (ex, ey) (S,) leaving the pose ``origin``; the
    whole rollouts px, py (S, K + 1) are read only when not ``single`` (see single_target).

    A rollout that reaches the station scores 180, less ``soonest_deg`` times the fraction of
    the horizon it takes to get there (0, the paper's: every arriving rollout ties). With a speed
    window many slow rollouts reach a near station within the horizon; scored alike, the one
    picked could graze the arrival circle at the horizon's end, tick after tick, and the vehicle
    circled its station just outside the arrival radius until the time limit."""
    nodes = goals.nodes_xy
    count = len(nodes)
    at_station = None
    if resolve_single(ex, ey, goals, origin, single):
        tx, ty = goals.first_xy
    else:
        gx, gy = nodes[:, 0], nodes[:, 1]
        near2 = (((px.ravel() - gx[:, None]) ** 2 + (py.ravel() - gy[:, None]) ** 2)
                 .reshape(count, *px.shape).min(axis=2).T)  # (S, G)
        prev = goals.prev_nodes_xy
        passed = (ex[:, None] - gx) * (gx - prev[:, 0]) + (ey[:, None] - gy) * (gy - prev[:, 1]) > 0.0
        if goals.ends_at_station:
            passed[:, -1] = False  # the station is reached, never passed
        # How many goals in a row each rollout reaches: the first unreached one's index.
        reached = np.zeros((len(ex), count + 1), dtype=bool)
        np.logical_or(near2 <= goals.radius2_m2, passed, out=reached[:, :count])
        n_reached = reached.argmin(axis=1)
        if goals.ends_at_station:
            at_station = n_reached == count
        target = nodes[np.minimum(n_reached, count - 1)]
        tx, ty = target[:, 0], target[:, 1]
    heading = heading_toward(ex, ey, final_heading, tx, ty)
    if at_station is None:
        return heading
    arrive = np.full(len(heading), 180.0)
    if soonest_deg > 0.0:
        sx, sy = nodes[-1]
        inside = (px - sx) ** 2 + (py - sy) ** 2 <= goals.radius2_m2[-1]  # (S, K + 1)
        arrive -= soonest_deg * inside.argmax(axis=1) / (px.shape[1] - 1)
    return np.where(at_station, arrive, heading)
