"""The compiled twins (numba) of :mod:`.sightline`'s depth and :mod:`.sightline_slope`'s open
clearance: the same numbers bit for bit (see :mod:`.jit`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from companion.planning.dwa.geometry import one_layout
from companion.planning.dwa.geometry_jit import polygon_point
from companion.planning.dwa.jit import jit

if TYPE_CHECKING:
    from companion.planning.dwa.snapshot import ObstacleSnapshot


def sightline_depths(ex: np.ndarray, ey: np.ndarray, other_xy: tuple[float, float], t_s: float,
                     snap: ObstacleSnapshot, keep: np.ndarray | None = None) -> np.ndarray:
    """:func:`.sightline.sightline_depths`, compiled: its operands built in one compiled pass
    (which also picks the obstacles ``keep`` marks); the product stays numpy's."""
    arrays = snap.arrays()
    rows, basis, len2, radius, n_p = _sight_frame(one_layout(ex), one_layout(ey), float(other_xy[0]),
                                                  float(other_xy[1]), float(t_s), arrays,
                                                  _ALL if keep is None else keep, keep is not None)
    return _sightline_depth(rows @ basis, len2, radius, len(radius), n_p, arrays[4].shape[1] if n_p else 0)


_ALL = np.ones(0, dtype=bool)  # the mask _sight_frame is given when it keeps every obstacle (not read)


def open_clearance(ex: np.ndarray, ey: np.ndarray, q: tuple[float, float], t_s: float,
                   snap: ObstacleSnapshot) -> np.ndarray:
    """:func:`.sightline_slope.open_clearance`, compiled."""
    return _open_clearance(ex, ey, float(q[0]), float(q[1]), float(t_s), snap.arrays())


@jit
def _sight_frame(ex, ey, qx, qy, t_s, obstacles, keep, masked):
    """_sightline_scores' operands for sight segments (ex, ey) -> q, over the obstacles
    ``keep`` marks (circles, then polygons; all when not ``masked``): the rows (the kept
    circle centres, polygon vertices, each predicted to t_s and relative to q, then the edge
    vectors) (R, 2), the basis [unit left normals | segment vectors] (2, 2S), the squared
    lengths (S,), the kept circles' radii and how many polygons are kept."""
    c_xy, c_vel, c_r, _, p_a, _, p_d, _, _, p_vel, _, _, _ = obstacles
    n_s = len(ex)
    len2 = np.empty(n_s)
    basis = np.empty((2, 2 * n_s))
    for i in range(n_s):
        dx = qx - ex[i]
        dy = qy - ey[i]
        v = dx * dx + dy * dy
        len2[i] = v if v > 1e-12 else 1e-12
        inv_len = 1.0 / np.sqrt(len2[i])
        basis[0, i] = -dy * inv_len
        basis[1, i] = dx * inv_len
        basis[0, n_s + i] = dx
        basis[1, n_s + i] = dy
    n_call, n_pall, n_e = len(c_xy), p_a.shape[0], p_a.shape[1]
    n_c = n_p = 0
    for c in range(n_call):
        n_c += not masked or keep[c]
    for p in range(n_pall):
        n_p += not masked or keep[n_call + p]
    rows = np.empty((n_c + 2 * n_p * n_e, 2))
    radius = np.empty(n_c)
    k = 0
    for c in range(n_call):
        if masked and not keep[c]:
            continue
        rows[k, 0] = c_xy[c, 0] + (c_vel[c, 0] * t_s - qx)
        rows[k, 1] = c_xy[c, 1] + (c_vel[c, 1] * t_s - qy)
        radius[k] = c_r[c]
        k += 1
    k = 0
    for p in range(n_pall):
        if masked and not keep[n_call + p]:
            continue
        sx = p_vel[p, 0] * t_s - qx
        sy = p_vel[p, 1] * t_s - qy
        for e in range(n_e):
            r = n_c + k * n_e + e
            rows[r, 0] = p_a[p, e, 0] + sx
            rows[r, 1] = p_a[p, e, 1] + sy
            rows[r + n_p * n_e, 0] = p_d[p, e, 0]
            rows[r + n_p * n_e, 1] = p_d[p, e, 1]
        k += 1
    return rows, basis, len2, radius, n_p


@jit
def _sightline_depth(m, len2, radius, n_c, n_p, n_e):
    """The paper's S from the projections ``m`` (rows, 2S) of circle centres, polygon
    vertices and edge vectors onto the S sight lines (see sightline._sightline_scores)."""
    n_s = len(len2)
    best = np.zeros(n_s)
    k0 = n_c + n_p * n_e
    for s in range(n_s):
        l2 = len2[s]
        top = 0.0  # numpy's S is max(0, every crossing's depth): a circle's is > 0
        for c in range(n_c):
            side, along = m[c, s], m[c, n_s + s]
            u = along / l2 + 1.0
            over = u - min(max(u, 0.0), 1.0)
            r = radius[c]
            value = r - abs(side) if side * side + over * over * l2 < r * r else 0.0
            top = max(top, value)
        for p in range(n_p):
            crossed = False
            hi, lo = -np.inf, np.inf
            for e in range(n_e):
                i = n_c + p * n_e + e
                sa, pa = m[i, s], m[i, n_s + s]
                sd, pd = m[k0 + p * n_e + e, s], m[k0 + p * n_e + e, n_s + s]
                if (sa > 0.0) != (sa + sd > 0.0):
                    w = pa + sa / -sd * pd
                    if w >= -l2 and w <= 0.0:
                        crossed = True
                hi = max(hi, sa)
                lo = min(lo, sa)
            if crossed:
                top = max(top, min(hi, -lo))
        best[s] = top
    return best


@jit
def _to_segments(ex, ey, qx, qy, px, py, radius, best):
    """best[i] = min(best[i], min over j of |point j - segment (ex, ey)[i] -> q| - radius[j])
    (sightline_slope.points_to_segments, reduced)."""
    for i in range(len(ex)):
        dx = qx - ex[i]
        dy = qy - ey[i]
        l2 = max(dx * dx + dy * dy, 1e-12)
        for j in range(len(px)):
            rx = px[j] - ex[i]
            ry = py[j] - ey[i]
            u = min(max((rx * dx + ry * dy) / l2, 0.0), 1.0)
            value = np.hypot(rx - u * dx, ry - u * dy) - radius[j]
            if value < best[i]:
                best[i] = value


@jit
def _open_clearance(ex, ey, qx, qy, t_s, obstacles):
    """sightline_slope.open_clearance: each segment (ex, ey)[i] -> q's clearance (S,) to the
    nearest true obstacle predicted to t_s (circles, polygon vertices, and the ends' own
    distance to each polygon)."""
    c_xy, c_vel, c_r, _, a, b, d, inv_len2, dx_per_dy, p_vel, _, _, _ = obstacles
    best = np.full(len(ex), np.inf)
    n_c, n_p, n_e = len(c_r), a.shape[0], a.shape[1]
    cx, cy = np.empty(n_c), np.empty(n_c)
    for c in range(n_c):
        cx[c] = c_xy[c, 0] + c_vel[c, 0] * t_s
        cy[c] = c_xy[c, 1] + c_vel[c, 1] * t_s
    _to_segments(ex, ey, qx, qy, cx, cy, c_r, best)
    if n_p == 0:
        return best
    vx, vy = np.empty(n_p * n_e), np.empty(n_p * n_e)
    for p in range(n_p):
        sx, sy = p_vel[p, 0] * t_s, p_vel[p, 1] * t_s
        for e in range(n_e):
            vx[p * n_e + e] = a[p, e, 0] + sx
            vy[p * n_e + e] = a[p, e, 1] + sy
    _to_segments(ex, ey, qx, qy, vx, vy, np.zeros(n_p * n_e), best)
    # The ends: a segment end inside a polygon, or nearer to it than any vertex is to the segment.
    at_q = np.inf
    ends = np.full(len(ex), np.inf)
    for p in range(n_p):
        sx, sy = p_vel[p, 0] * t_s, p_vel[p, 1] * t_s
        at_q = min(at_q, polygon_point(qx - sx, qy - sy, p, a, b, d, inv_len2, dx_per_dy))
        for i in range(len(ex)):
            ends[i] = min(ends[i], polygon_point(ex[i] - sx, ey[i] - sy, p, a, b, d, inv_len2, dx_per_dy))
    for i in range(len(ex)):
        best[i] = min(best[i], min(ends[i], at_q))
    return best



