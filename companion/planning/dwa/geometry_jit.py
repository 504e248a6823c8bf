"""The compiled twins (numba) of :mod:`.geometry`'s clearances and of the snapshot's culling
(:meth:`.ObstacleSnapshot.near_mask`): the same numbers bit for bit (see :mod:`.jit`)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from companion.planning.dwa.geometry import one_layout
from companion.planning.dwa.jit import inline, jit

if TYPE_CHECKING:
    from companion.planning.dwa.snapshot import ObstacleSnapshot


def inflated_clearance(px: np.ndarray, py: np.ndarray, t_s: np.ndarray, snap: ObstacleSnapshot) -> np.ndarray:
    """:func:`.geometry.inflated_clearance`, compiled."""
    px, py, t_s = one_layout(px), one_layout(py), one_layout(t_s)
    n_c = len(snap.circle_ids)
    out = np.empty((n_c + len(snap.poly_ids), len(px)))
    arrays = snap.arrays()
    if n_c:
        _circle_clearance(px, py, t_s, arrays, out, 0)
    if snap.poly_ids:
        _polygon_clearance(px, py, t_s, arrays, snap.poly_margin_m, out, n_c)
    return out


def polygon_signed_distance(px: np.ndarray, py: np.ndarray, t_s: np.ndarray, snap: ObstacleSnapshot) -> np.ndarray:
    """:func:`.geometry.polygon_signed_distance`, compiled."""
    px, py, t_s = one_layout(px), one_layout(py), one_layout(t_s)
    out = np.empty((len(snap.poly_ids), len(px)))
    _polygon_clearance(px, py, t_s, snap.arrays(), np.zeros(len(snap.poly_ids)), out, 0)
    return out


def near_mask(snap: ObstacleSnapshot, x_m: float, y_m: float, reach_m: float, horizon_s: float,
              to_xy: tuple[float, float] | None = None) -> tuple[np.ndarray, int]:
    """:meth:`.ObstacleSnapshot.near_mask`, compiled."""
    to_x, to_y = (x_m, y_m) if to_xy is None else to_xy
    where = (float(x_m), float(y_m), float(reach_m), float(horizon_s))
    return _near_mask(snap.bound_xy_m, snap.bound_radius_m, snap.speed_m_s, where, (float(to_x), float(to_y)),
                      to_xy is not None)


@jit
def _circle_clearance(px, py, t_s, obstacles, out, row0):
    """out[row0 + c, n] = |point n at t_n - centre c| - radius - margin (predicted circle)."""
    xy, vel, radius, margin, _, _, _, _, _, _, _, _, _ = obstacles
    for c in range(len(radius)):
        cx, cy, vx, vy = xy[c, 0], xy[c, 1], vel[c, 0], vel[c, 1]
        r, m = radius[c], margin[c]
        moves = vx != 0.0 or vy != 0.0
        row = out[row0 + c]
        for n in range(len(px)):
            dx = px[n] - cx
            dy = py[n] - cy
            if moves:
                dx -= vx * t_s[n]
                dy -= vy * t_s[n]
            row[n] = np.hypot(dx, dy) - r - m


@inline
def polygon_point(qx, qy, p, a, b, d, inv_len2, dx_per_dy):
    """Signed distance of (qx, qy) to true polygon p: negative inside (crossing number)."""
    inside = False
    best = np.inf
    for e in range(a.shape[1]):
        ax, ay = a[p, e, 0], a[p, e, 1]
        apx = qx - ax
        apy = qy - ay
        if ((ay > qy) != (b[p, e, 1] > qy)) and apx < apy * dx_per_dy[p, e]:
            inside = not inside
        abx, aby = d[p, e, 0], d[p, e, 1]
        u = apx * abx
        u += apy * aby
        u *= inv_len2[p, e]
        u = min(max(u, 0.0), 1.0)
        ex = apx - u * abx
        ey = apy - u * aby
        d2 = ex * ex + ey * ey
        if d2 < best:
            best = d2
    dist = math.sqrt(best)
    return -dist if inside else dist


@jit
def _polygon_clearance(px, py, t_s, obstacles, margin, out, row0):
    """out[row0 + p, n] = signed distance of point n at t_n to true polygon p, minus
    margin[p]; a moving polygon in its own frame (the point moves by -v t)."""
    _, _, _, _, a, b, d, inv_len2, dx_per_dy, vel, _, _, _ = obstacles
    for p in range(a.shape[0]):
        vx, vy, m = vel[p, 0], vel[p, 1], margin[p]
        row = out[row0 + p]
        for n in range(len(px)):
            row[n] = polygon_point(px[n] - vx * t_s[n], py[n] - vy * t_s[n], p, a, b, d, inv_len2,
                                    dx_per_dy) - m


@jit
def _near_mask(bound_xy, bound_r, speed, where, to, segment):
    """ObstacleSnapshot.near_mask: which bounding discs, moving at their speed for horizon,
    come within reach of (x, y), or of the segment (x, y) -> (to_x, to_y); and how many.
    ``where``: (x, y, reach, horizon); ``to``: (to_x, to_y)."""
    x, y, reach, horizon = where
    to_x, to_y = to
    n = len(bound_r)
    keep = np.empty(n, dtype=np.bool_)
    kept = 0
    dx, dy = to_x - x, to_y - y
    len2 = dx * dx + dy * dy
    for i in range(n):
        rx = bound_xy[i, 0] - x
        ry = bound_xy[i, 1] - y
        if not segment:
            d = math.sqrt(rx * rx + ry * ry)
        elif len2 == 0.0:
            d = np.hypot(rx, ry)
        else:
            u = min(max((rx * dx + ry * dy) / len2, 0.0), 1.0)
            d = np.hypot(rx - u * dx, ry - u * dy)
        keep[i] = d - bound_r[i] - speed[i] * horizon <= reach
        kept += keep[i]
    return keep, kept



