"""The compiled twin (numba) of :func:`.recovery.spin_checks`: the obstacle rule and the distance
critic on the spin recovery's rollouts, the same verdicts and, where a rollout is legal, the same
distance bit for bit (see :mod:`.jit`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from companion.planning.dwa.geometry import one_layout
from companion.planning.dwa.geometry_jit import polygon_point
from companion.planning.dwa.jit import jit

if TYPE_CHECKING:
    from companion.planning.dwa.config import DwaConfig
    from companion.planning.dwa.recovery import HoverCheck


def spin_checks(px: np.ndarray, py: np.ndarray, config: DwaConfig, hover: HoverCheck, ok_inf: np.ndarray,
                ok_true: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`.recovery.spin_checks`, compiled: rollout by rollout, point by point until the
    rollout is illegal on both footprints, each point over the obstacles of its grid cell."""
    field = hover.field
    floors = (one_layout(hover.floor_inflated[:, 0]), one_layout(hover.floor_true[:, 0]),
              one_layout(hover.margins[:, 0]))
    bounds = (one_layout(field.bound_xy_m), one_layout(field.bound_radius_m), one_layout(field.speed_m_s))
    out_inf, out_true = ok_inf.copy(), ok_true.copy()
    distance = _spin_checks(one_layout(px.ravel()), one_layout(py.ravel()), config.rec_point_times_s, px.shape[1],
                            field.arrays(), (floors, bounds), (out_inf, out_true), float(config.distance_saturation_m))
    return out_inf, out_true, distance


@jit
def _grid(px, py, bound_xy, reach, cell):
    """The obstacles by grid cell over the points' box: cell c of the (nx, ny) grid of side
    ``cell`` from (x0, y0) holds ``members[first[c]:first[c + 1]]``, every obstacle whose disc
    (centre ``bound_xy``, radius ``reach``) overlaps the cell."""
    x0, x1, y0, y1 = px.min(), px.max(), py.min(), py.max()
    nx = int((x1 - x0) / cell) + 1
    ny = int((y1 - y0) / cell) + 1
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
    return first, members, x0, y0, ny


@jit
def _spin_checks(px, py, t_s, n_k, obstacles, limits, ok, saturation):
    """Narrows ``ok`` = (ok_inf, ok_true) (R,) in place to the rollouts of n_k points (px, py) at
    t_s that keep clear of every obstacle (inflated: no deeper than the floor; true: with the
    margin given back), points after the first only; returns the distance critic (R,).

    A point farther from an obstacle's bounding disc than the saturation plus 1 m can neither
    break the rule (its clearance exceeds 1 m, the floors are <= 0) nor set the critic: each
    point is measured only to the obstacles of its grid cell, those whose bounding disc, moving
    at its speed until the last point's time, comes that near the cell."""
    c_xy, c_vel, c_r, c_m, p_a, p_b, p_d, p_inv_len2, p_dx_per_dy, p_vel, p_m, p_centre, p_bound = obstacles
    (floor_inf, floor_true, margins), (bound_xy, bound_r, speed) = limits
    ok_inf, ok_true = ok
    n_c = len(c_r)
    n_r = len(px) // n_k
    beyond = (saturation if saturation > 0.0 else 0.0) + 1.0
    distance = np.full(n_r, saturation)
    reach = np.empty(len(bound_r))
    t_end = t_s.max()
    for o in range(len(bound_r)):
        reach[o] = bound_r[o] + speed[o] * t_end + beyond
    cell = max(_CELL_M, (max(px.max() - px.min(), py.max() - py.min()) + 1.0) / _CELLS_ACROSS)
    first, members, x0, y0, ny = _grid(px, py, bound_xy, reach, cell)
    for r in range(n_r):
        a_inf, a_true = ok_inf[r], ok_true[r]
        if not (a_inf or a_true):
            continue
        lowest = np.inf
        for n in range(r * n_k + 1, (r + 1) * n_k):
            c = int((px[n] - x0) / cell) * ny + int((py[n] - y0) / cell)
            for m in range(first[c], first[c + 1]):
                o = members[m]
                if o < n_c:  # geometry_jit._circle_clearance's operations
                    dx = px[n] - c_xy[o, 0]
                    dy = py[n] - c_xy[o, 1]
                    if c_vel[o, 0] != 0.0 or c_vel[o, 1] != 0.0:
                        dx -= c_vel[o, 0] * t_s[n]
                        dy -= c_vel[o, 1] * t_s[n]
                    lim = c_r[o] + c_m[o] + beyond
                    if dx * dx + dy * dy > lim * lim:
                        continue
                    v = np.hypot(dx, dy) - c_r[o] - c_m[o]
                else:  # geometry_jit._polygon_clearance's operations
                    p = o - n_c
                    qx = px[n] - p_vel[p, 0] * t_s[n]
                    qy = py[n] - p_vel[p, 1] * t_s[n]
                    dx = qx - p_centre[p, 0]
                    dy = qy - p_centre[p, 1]
                    lim = p_bound[p] + p_m[p] + beyond
                    if dx * dx + dy * dy > lim * lim:
                        continue
                    v = polygon_point(qx, qy, p, p_a, p_b, p_d, p_inv_len2, p_dx_per_dy) - p_m[p]
                if a_inf and not v >= floor_inf[o] - 1e-9:
                    a_inf = False
                if a_true and not v + margins[o] >= floor_true[o] - 1e-9:
                    a_true = False
                if v < lowest:
                    lowest = v
            if not (a_inf or a_true):
                break
        ok_inf[r], ok_true[r] = a_inf, a_true
        # np.clip's order: the lower bound, then the upper (+0.0 for a zero of either sign)
        lowest = lowest if lowest > 0.0 else 0.0
        distance[r] = lowest if lowest < saturation else saturation
    return distance


# The grid's cell: 20 m, coarser when the points span more than 64 cells across.
_CELL_M = 20.0
_CELLS_ACROSS = 64
