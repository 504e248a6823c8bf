"""The compiled twins (numba) of :func:`.recovery.spin_checks`, the obstacle rule and the distance
critic on the spin recovery's rollouts (the same verdicts and, where a rollout is legal, the same
distance bit for bit), and of :func:`.recovery.braking_checks`, the hover check's obstacles (the
same bits; see :mod:`.jit`)."""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING

import numpy as np

from companion.planning.dwa.geometry import one_layout
from companion.planning.dwa.geometry_jit import polygon_point
from companion.planning.dwa.jit import jit

if TYPE_CHECKING:
    from companion.planning.dwa.config import DwaConfig
    from companion.planning.dwa.recovery import HoverCheck
    from companion.planning.dwa.snapshot import ObstacleSnapshot


def spin_checks(pts: np.ndarray, config: DwaConfig, hover: HoverCheck, ok_inf: np.ndarray,
                ok_true: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`.recovery.spin_checks`, compiled: the rule rollout by rollout, point by point until
    the rollout is illegal on both footprints, then the critic on those still legal, each point
    over the obstacles of its grid cell."""
    field = hover.field
    floors = (one_layout(hover.floor_inflated[:, 0]), one_layout(hover.floor_true[:, 0]),
              one_layout(hover.margins[:, 0]))
    bounds = (one_layout(field.bound_xy_m), one_layout(field.bound_radius_m), one_layout(field.speed_m_s))
    # Every point is within cruise x horizon of the pose (point 0), the last at the longest spin
    # plus the horizon: the grids' square and time (any that hold every point will do).
    box = (float(pts[0, 0, 0]), float(pts[0, 0, 1]), config.reach_m + 1.0, config.spin_time_s + config.horizon_s)
    out_inf, out_true = ok_inf.copy(), ok_true.copy()
    n_k = pts.shape[1]
    distance = _spin_checks(one_layout(pts.reshape(-1, 2)), config.rec_point_times_s, n_k, check_order(n_k),
                            field.arrays(), (floors, bounds), (out_inf, out_true), float(config.distance_saturation_m),
                            box)
    return out_inf, out_true, distance


@functools.cache
def check_order(points: int) -> np.ndarray:
    """The order in which the compiled spin checks visit a rollout's points after the first (1
    to ``points`` - 1): every third from the far end, then those between. An obstacle across a
    rollout covers several points in a row, and the far points sweep the most ground, so a
    blocked rollout is found after a few points. Any order gives the same verdicts."""
    order = np.array([k for start in range(points - 1, points - 4, -1) for k in range(start, 0, -3)], dtype=np.int64)
    order.setflags(write=False)
    return order


@jit
def _spin_checks(xy, t_s, n_k, order, obstacles, limits, ok, saturation, box):
    """Narrows ``ok`` = (ok_inf, ok_true) (R,) in place to the rollouts of n_k points ``xy``
    (R * n_k, 2) at t_s that keep clear of every obstacle (inflated: no deeper than the floor;
    true: with the margin given back), points after the first only, visited in ``order``;
    returns the distance critic (R,) of those still legal on either footprint (the saturation
    elsewhere). ``box``: (x, y, r, t), every point within r of (x, y) and at t or earlier.

    Two sweeps (:func:`_sweep`): the rule, then the critic on the rollouts still legal. Only an
    obstacle within 1 m of a point can break the rule (the floors are <= 0), so the rule's grid
    holds few; only one within the saturation plus 1 m can set the critic, and when the vehicle
    is boxed in no rollout is left for that sweep."""
    x, y, r, t_end = box
    bound_xy, bound_r, speed = limits[1]
    distance = np.full(len(xy) // n_k, saturation)
    cell = max(_RULE_CELL_M, 2.0 * r / _CELLS_ACROSS)
    grid = _grid(x - r, y - r, 2.0 * r, bound_xy, bound_r + speed * t_end + 1.0, cell)
    if _sweep(xy, t_s, n_k, order, obstacles, limits, ok, grid, 1.0, True, distance):
        beyond = (saturation if saturation > 0.0 else 0.0) + 1.0
        cell = max(_CELL_M, 2.0 * r / _CELLS_ACROSS)
        grid = _grid(x - r, y - r, 2.0 * r, bound_xy, bound_r + speed * t_end + beyond, cell)
        _sweep(xy, t_s, n_k, order, obstacles, limits, ok, grid, beyond, False, distance)
    return distance


@jit
def _grid(x0, y0, side, bound_xy, reach, cell):
    """The obstacles by grid cell over the square of ``side`` from (x0, y0): cell c of the
    (nx, ny) grid of side ``cell`` holds ``members[first[c]:first[c + 1]]``, every obstacle whose
    disc (centre ``bound_xy``, radius ``reach``) overlaps the cell. Returns (first, members, x0,
    y0, ny, cell)."""
    nx = ny = int(side / cell) + 1
    count = np.zeros(nx * ny + 1, dtype=np.int64)
    span = np.empty((len(reach), 4), dtype=np.int64)
    for o in range(len(reach)):
        i0 = max(int(np.floor((bound_xy[o, 0] - reach[o] - x0) / cell)), 0)
        i1 = min(int(np.floor((bound_xy[o, 0] + reach[o] - x0) / cell)), nx - 1)
        j0 = max(int(np.floor((bound_xy[o, 1] - reach[o] - y0) / cell)), 0)
        j1 = min(int(np.floor((bound_xy[o, 1] + reach[o] - y0) / cell)), ny - 1)
        span[o, 0], span[o, 1], span[o, 2], span[o, 3] = i0, i1, j0, j1
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                count[i * ny + j + 1] += 1
    first = np.cumsum(count)
    members = np.empty(first[-1], dtype=np.int64)
    fill = first[:-1].copy()
    for o in range(len(reach)):
        for i in range(span[o, 0], span[o, 1] + 1):
            for j in range(span[o, 2], span[o, 3] + 1):
                members[fill[i * ny + j]] = o
                fill[i * ny + j] += 1
    return first, members, x0, y0, ny, cell


@jit
def _sweep(xy, t_s, n_k, order, obstacles, limits, ok, grid, beyond, rule, distance):
    """One sweep over the rollouts still legal on either footprint, each point measured to the
    obstacles of its ``grid`` cell (:func:`_grid`) and a pair of point and obstacle farther than
    ``beyond`` from its bounding disc left out. ``rule``: the obstacle rule, rollout by rollout
    until illegal on both footprints, narrowing ``ok``; returns how many are still legal. Else
    the critic of each, over every point, into ``distance`` (np.clip'd to [0, its value]); a
    pair that cannot come nearer than the nearest so far is left out too."""
    c_xy, c_vel, c_r, c_m, p_a, p_b, p_d, p_inv_len2, p_dx_per_dy, p_vel, p_m, p_centre, p_bound = obstacles
    floor_inf, floor_true, margins = limits[0]
    ok_inf, ok_true = ok
    first, members, x0, y0, ny, cell = grid
    n_c = len(c_r)
    legal = 0
    hit = 0
    for r in range(len(xy) // n_k):
        a_inf, a_true = ok_inf[r], ok_true[r]
        if not (a_inf or a_true):
            continue
        lowest = np.inf
        for i in range(-1, len(order)):
            k = hit if i < 0 else order[i]
            if k == 0 or (i >= 0 and k == hit):
                continue
            n = r * n_k + k
            x, y, t = xy[n, 0], xy[n, 1], t_s[n]
            c = int((x - x0) / cell) * ny + int((y - y0) / cell)
            for m in range(first[c], first[c + 1]):
                o = members[m]
                if o < n_c:  # geometry_jit._circle_clearance's operations
                    dx = x - c_xy[o, 0]
                    dy = y - c_xy[o, 1]
                    if c_vel[o, 0] != 0.0 or c_vel[o, 1] != 0.0:
                        dx -= c_vel[o, 0] * t
                        dy -= c_vel[o, 1] * t
                    lim = c_r[o] + c_m[o] + (beyond if rule or lowest > beyond else _above(lowest))
                    if dx * dx + dy * dy > lim * lim:
                        continue
                    v = np.hypot(dx, dy) - c_r[o] - c_m[o]
                else:  # geometry_jit._polygon_clearance's operations
                    p = o - n_c
                    qx = x - p_vel[p, 0] * t
                    qy = y - p_vel[p, 1] * t
                    dx = qx - p_centre[p, 0]
                    dy = qy - p_centre[p, 1]
                    lim = p_bound[p] + p_m[p] + (beyond if rule or lowest > beyond else _above(lowest))
                    if dx * dx + dy * dy > lim * lim:
                        continue
                    v = polygon_point(qx, qy, p, p_a, p_b, p_d, p_inv_len2, p_dx_per_dy) - p_m[p]
                if not rule:
                    lowest = v if v < lowest else lowest
                    continue
                if a_inf and not v >= floor_inf[o] - 1e-9:
                    a_inf = False
                if a_true and not v + margins[o] >= floor_true[o] - 1e-9:
                    a_true = False
            if not (a_inf or a_true):
                hit = k
                break
        if rule:
            ok_inf[r], ok_true[r] = a_inf, a_true
            legal += a_inf or a_true
        else:  # np.clip's order: the lower bound, then the upper (+0.0 for a zero of either sign)
            lowest = lowest if lowest > 0.0 else 0.0
            distance[r] = lowest if lowest < distance[r] else distance[r]
    return legal


@jit
def _above(lowest):
    """How far from its bounding disc a point can be and still come nearer an obstacle than
    ``lowest``, the nearest so far, or than 0 (the critic is clipped at 0): a little more than
    either, for rounding."""
    return (lowest if lowest > 0.0 else 0.0) + 1e-6


def braking_checks(bx: np.ndarray, by: np.ndarray, t_s: np.ndarray,
                   snap: ObstacleSnapshot) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`.recovery.braking_checks`, compiled: an obstacle that stays put is measured at each
    point once, not at every time."""
    floor_inf, floor_true = np.empty((snap.count, 1)), np.empty((snap.count, 1))
    clear_inf, clear_true = np.ones(len(t_s), dtype=bool), np.ones(len(t_s), dtype=bool)
    _braking_checks(one_layout(bx), one_layout(by), one_layout(t_s), snap.arrays(),
                    (floor_inf[:, 0], floor_true[:, 0], clear_inf, clear_true))
    return floor_inf, floor_true, clear_inf, clear_true


@jit
def _braking_checks(bx, by, t_s, obstacles, out):
    """Fills ``out`` = (floor_inf, floor_true (O,), clear_inf, clear_true (T,), all True) as
    :func:`.recovery.braking_checks` returns them."""
    c_xy, c_vel, c_r, c_m, p_a, p_b, p_d, p_inv_len2, p_dx_per_dy, p_vel, p_m, _, _ = obstacles
    floor_inf, floor_true, clear_inf, clear_true = out
    n_c = len(c_r)
    lowest = np.empty(len(t_s))
    for o in range(len(floor_inf)):
        vel = c_vel[o] if o < n_c else p_vel[o - n_c]
        moves = vel[0] != 0.0 or vel[1] != 0.0
        margin = c_m[o] if o < n_c else p_m[o - n_c]
        for k in range(len(t_s)):  # the first point at the first time, then the worst point at each
            if k > 1 and not moves:  # the same points, the same clearances
                lowest[k] = lowest[1]
                continue
            v_min = np.inf
            for j in range(len(bx) if k else 1):
                if o < n_c:  # geometry_jit._circle_clearance's operations
                    dx = bx[j] - c_xy[o, 0]
                    dy = by[j] - c_xy[o, 1]
                    if moves:
                        dx -= c_vel[o, 0] * t_s[k]
                        dy -= c_vel[o, 1] * t_s[k]
                    v = np.hypot(dx, dy) - c_r[o] - c_m[o]
                else:  # geometry_jit._polygon_clearance's operations
                    p = o - n_c
                    v = polygon_point(bx[j] - p_vel[p, 0] * t_s[k], by[j] - p_vel[p, 1] * t_s[k], p, p_a, p_b, p_d,
                                      p_inv_len2, p_dx_per_dy) - p_m[p]
                v_min = v if v < v_min else v_min
            lowest[k] = v_min
        here_true = lowest[0] + margin
        floor_inf[o] = lowest[0] if lowest[0] < 0.0 else 0.0
        floor_true[o] = here_true if here_true < 0.0 else 0.0
        for k in range(len(t_s)):
            if not lowest[k] >= floor_inf[o] - 1e-9:
                clear_inf[k] = False
            if not lowest[k] + margin >= floor_true[o] - 1e-9:
                clear_true[k] = False


# The grids' cells: the rule's 10 m, the critic's 20 m, coarser when the points span more than 64
# cells across.
_RULE_CELL_M = 10.0
_CELL_M = 20.0
_CELLS_ACROSS = 64
