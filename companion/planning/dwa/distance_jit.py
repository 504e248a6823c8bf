"""The compiled twins (numba) of :mod:`.distance`: the obstacle rule with the distance critic
from the clearances, and the fused obstacle pass of a tick (clearances, the rule per point and
per rollout, the critic) in one compiled call. The same numbers bit for bit (see :mod:`.jit`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from companion.planning.dwa.geometry import one_layout
from companion.planning.dwa.geometry_jit import polygon_point
from companion.planning.dwa.jit import jit

if TYPE_CHECKING:
    from companion.planning.dwa.config import DwaConfig
    from companion.planning.dwa.snapshot import Culled


def obstacle_and_distance(clear: np.ndarray, shape: tuple[int, int],
                          saturation_m: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`.distance.obstacle_and_distance`, compiled."""
    return _obstacle_terms(one_layout(clear), int(shape[1]), float(saturation_m))


def obstacle_rule(px: np.ndarray, py: np.ndarray, culled: Culled, config: DwaConfig,
                  times_s: np.ndarray | None = None) -> tuple[np.ndarray | None, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`.distance.obstacle_rule` in one compiled pass over the snapshot's obstacles that
    ``culled`` keeps (read through its mask: the culled subset is built only if read), with the
    rule per rollout too. The clearances are None when the pass left out those that cannot
    matter (above the saturation)."""
    shape = px.shape
    clear, ok, distance, legal, exact = _obstacle_pass(
        one_layout(px.ravel()), one_layout(py.ravel()), config.point_times_s if times_s is None else times_s,
        culled.snapshot.arrays(), culled.keep,
        shape[1], config.distance_saturation_m)
    return clear if exact else None, ok.reshape(shape), distance, legal


@jit
def _obstacle_terms(clear, n_k, saturation):
    """From the clearances (O, R * n_k) of R rollouts of n_k points (O >= 1): the obstacle
    rule per point (R * n_k,) (legality.obstacle_ok), the distance critic per rollout (R,)
    and the distance critic per rollout (R,) (distance.obstacle_and_distance: the nearest
    clearance after the pose, in [0, saturation])."""
    n_o, n_pts = clear.shape
    lowest = np.empty(n_pts)
    for n in range(n_pts):
        v = clear[0, n]
        for o in range(1, n_o):
            if clear[o, n] < v:
                v = clear[o, n]
        lowest[n] = v
    outside = True
    for o in range(n_o):
        if clear[o, 0] < 0.0:
            outside = False
    ok = np.empty(n_pts, dtype=np.bool_)
    if outside:
        for n in range(n_pts):
            ok[n] = lowest[n] >= -1e-9
    else:
        floor = np.empty(n_o)
        for o in range(n_o):
            here = clear[o, 0]
            floor[o] = (here if here < 0.0 else 0.0) - 1e-9
        for n in range(n_pts):
            good = True
            for o in range(n_o):
                if not clear[o, n] >= floor[o]:
                    good = False
                    break
            ok[n] = good
    n_r = n_pts // n_k
    distance = np.empty(n_r)
    for r in range(n_r):
        v = lowest[r * n_k + 1]
        for k in range(2, n_k):
            if lowest[r * n_k + k] < v:
                v = lowest[r * n_k + k]
        # np.maximum / np.minimum give the second on a tie (+0.0 for max(-0.0, 0.0)), so the
        # sign of a zero the minima above may pick differently from numpy's never shows.
        v = v if v > 0.0 else 0.0
        distance[r] = v if v < saturation else saturation
    return ok, distance


@jit
def _obstacle_pass(px, py, t_s, obstacles, keep, n_k, saturation):
    """Clearances (O, N) of the N = R * n_k points (px, py) at t_s to the O circles and
    polygons that ``keep`` marks (circles, then polygons: the culled subset's rows), the
    obstacle rule per point (N,), the distance critic (R,), whether each rollout obeys the
    rule at every point after the pose (R,), and whether every clearance is exact.

    A point farther from an obstacle's bounding disc (a polygon's ``p_centre``, ``p_bound``), or
    from an inflated polygon's bounding box, than the saturation plus 1 m has a clearance above
    the saturation: it can neither break the rule nor set the distance critic, so its clearance
    is not worked out (+inf stands for it, and the rule and critic come out the same). The
    caller works the clearances out in
    full when it reads them (the escape, with no legal rollout)."""
    c_xy, c_vel, c_r, c_m, p_a, p_b, p_d, p_inv_len2, p_dx_per_dy, p_vel, p_m, p_centre, p_bound = obstacles
    n_call, n_pall = len(c_r), p_a.shape[0]
    n_c = n_p = 0
    for c in range(n_call):
        n_c += keep[c]
    for p in range(n_pall):
        n_p += keep[n_call + p]
    clear = np.empty((n_c + n_p, len(px)))
    exact = True
    beyond = (saturation if saturation > 0.0 else 0.0) + 1.0
    k = 0
    for c in range(n_call):
        if not keep[c]:
            continue
        cx, cy, vx, vy = c_xy[c, 0], c_xy[c, 1], c_vel[c, 0], c_vel[c, 1]
        r, m = c_r[c], c_m[c]
        moves = vx != 0.0 or vy != 0.0
        lim = r + m + beyond
        lim2 = lim * lim
        row = clear[k]
        k += 1
        for n in range(len(px)):  # geometry_jit._circle_clearance's operations, where needed
            dx = px[n] - cx
            dy = py[n] - cy
            if moves:
                dx -= vx * t_s[n]
                dy -= vy * t_s[n]
            if dx * dx + dy * dy > lim2:
                row[n] = np.inf
                exact = False
            else:
                row[n] = np.hypot(dx, dy) - r - m
    for p in range(n_pall):
        if not keep[n_call + p]:
            continue
        vx, vy, m = p_vel[p, 0], p_vel[p, 1], p_m[p]
        lim = p_bound[p] + m + beyond
        lim2 = lim * lim
        # the polygon's bounding box: no nearer to it than to the box (tighter than the disc)
        x0 = x1 = p_a[p, 0, 0]
        y0 = y1 = p_a[p, 0, 1]
        for e in range(1, p_a.shape[1]):
            x0, x1 = min(x0, p_a[p, e, 0]), max(x1, p_a[p, e, 0])
            y0, y1 = min(y0, p_a[p, e, 1]), max(y1, p_a[p, e, 1])
        box = m + beyond
        box2 = box * box if box > 0.0 else np.inf
        row = clear[k]
        k += 1
        for n in range(len(px)):  # geometry_jit._polygon_clearance's operations, where needed
            qx = px[n] - vx * t_s[n]
            qy = py[n] - vy * t_s[n]
            dx = qx - p_centre[p, 0]
            dy = qy - p_centre[p, 1]
            bx = x0 - qx if qx < x0 else qx - x1 if qx > x1 else 0.0
            by = y0 - qy if qy < y0 else qy - y1 if qy > y1 else 0.0
            if dx * dx + dy * dy > lim2 or bx * bx + by * by > box2:
                row[n] = np.inf
                exact = False
            else:
                row[n] = polygon_point(qx, qy, p, p_a, p_b, p_d, p_inv_len2, p_dx_per_dy) - m
    ok, distance = _obstacle_terms(clear, n_k, saturation)
    n_r = len(px) // n_k
    legal = np.empty(n_r, dtype=np.bool_)
    for r in range(n_r):
        good = True
        for j in range(r * n_k + 1, (r + 1) * n_k):
            if not ok[j]:
                good = False
                break
        legal[r] = good
    return clear, ok, distance, legal, exact



