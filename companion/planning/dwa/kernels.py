"""Compiled (numba) versions of the tick's per-point kernels (clearance to circles and polygons,
the sightline critics, culling, the single-target heading critic), when numba is installed (the
``fast`` extra); None otherwise, and the numpy kernels run.

Each kernel does, per element, exactly the floating-point operations of its numpy twin in the
same order (no fast-math, no contraction into fused multiply-adds), so the results are bit for
bit the same: ``tests/planning/test_kernels.py`` checks this against the numpy code. What numpy
does as a matrix product stays in numpy (BLAS may fuse multiply-adds), and so do sums (numpy's
pairwise summation is not a loop's). What is saved is numpy's temporaries, large for a speed
window against polygons, and its per-call overhead on small arrays.

``cache=True`` keeps the compiled code beside this file (``__pycache__``), so that bench
workers and later runs load it instead of compiling again.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np

try:
    import numba
except ImportError:  # the numpy kernels run instead
    numba = None

__all__ = ["circle_clearance", "heading_toward", "near_mask", "numpy_only", "open_clearance", "polygon_clearance", "sightline_depth"]
_NAMES = ("circle_clearance", "polygon_clearance", "sightline_depth", "open_clearance", "near_mask",
          "heading_toward")

circle_clearance = polygon_clearance = sightline_depth = open_clearance = near_mask = heading_toward = None

if numba is not None:
    _jit = numba.njit(cache=True, nogil=True, error_model="numpy")
    _inline = numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")

    @_jit
    def circle_clearance(px, py, t_s, xy, vel, radius, margin, out, row0):  # noqa: F811
        """out[row0 + c, n] = |point n at t_n - centre c| - radius - margin (predicted circle)."""
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

    @_jit
    def heading_toward(ex, ey, final_heading, tx, ty):  # noqa: F811
        """The heading critic (S,) toward one target (tx, ty): 180 - |heading - bearing| in deg."""
        out = np.empty(len(ex))
        for i in range(len(ex)):
            bearing = np.arctan2(ty - ey[i], tx - ex[i])
            deviation = abs((final_heading[i] - bearing + np.pi) % (2.0 * np.pi) - np.pi)
            out[i] = 180.0 - np.degrees(deviation)
        return out

    @_jit
    def near_mask(bound_xy, bound_r, speed, x, y, reach, horizon, to_x, to_y, segment):  # noqa: F811
        """ObstacleSnapshot.near_mask: which bounding discs, moving at their speed for horizon,
        come within reach of (x, y), or of the segment (x, y) -> (to_x, to_y); and how many."""
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

    @_inline
    def _polygon_point(qx, qy, p, a, b, d, inv_len2, dx_per_dy):
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

    @_jit
    def polygon_clearance(px, py, t_s, a, b, d, inv_len2, dx_per_dy, vel, margin, out, row0):  # noqa: F811
        """out[row0 + p, n] = signed distance of point n at t_n to true polygon p, minus
        margin[p]; a moving polygon in its own frame (the point moves by -v t)."""
        for p in range(a.shape[0]):
            vx, vy, m = vel[p, 0], vel[p, 1], margin[p]
            row = out[row0 + p]
            for n in range(len(px)):
                row[n] = _polygon_point(px[n] - vx * t_s[n], py[n] - vy * t_s[n], p, a, b, d, inv_len2,
                                        dx_per_dy) - m

    @_jit
    def sightline_depth(m, len2, radius, n_c, n_p, n_e):  # noqa: F811
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

    @_jit
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

    @_jit
    def open_clearance(ex, ey, qx, qy, t_s, c_xy, c_vel, c_r, a, b, d, inv_len2, dx_per_dy, p_vel):  # noqa: F811
        """sightline_slope.open_clearance: each segment (ex, ey)[i] -> q's clearance (S,) to the
        nearest true obstacle predicted to t_s (circles, polygon vertices, and the ends' own
        distance to each polygon)."""
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
            at_q = min(at_q, _polygon_point(qx - sx, qy - sy, p, a, b, d, inv_len2, dx_per_dy))
            for i in range(len(ex)):
                ends[i] = min(ends[i], _polygon_point(ex[i] - sx, ey[i] - sy, p, a, b, d, inv_len2, dx_per_dy))
        for i in range(len(ex)):
            best[i] = min(best[i], min(ends[i], at_q))
        return best


@contextmanager
def numpy_only() -> Iterator[None]:
    """Run the numpy kernels inside the block, numba or not (tests and benchmarks compare the two;
    it swaps module globals, so not while another thread plans)."""
    saved = {name: globals()[name] for name in _NAMES}
    globals().update(dict.fromkeys(_NAMES))
    try:
        yield
    finally:
        globals().update(saved)
