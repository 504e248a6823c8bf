"""Compiled (numba) versions of the tick's per-point kernels (clearance to circles and polygons,
the sightline critics, culling, the single-target heading critic), when numba is installed (the
``fast`` extra); None otherwise, and the numpy kernels run. The planner reaches them through
:mod:`.kernels`, with those of :mod:`.kernels_tick` and :mod:`.kernels_fused`.

Each kernel does, per element, exactly the floating-point operations of its numpy twin in the
same order (no fast-math, no contraction into fused multiply-adds), and both call the C
library's elementary functions (numpy's AVX-512 arctan2 does not: see ``libm``), so the results
are bit for bit the same: ``tests/planning/test_kernels.py`` checks this against the numpy code. What numpy
does as a matrix product stays in numpy (BLAS may fuse multiply-adds), and so do sums (numpy's
pairwise summation is not a loop's). What is saved is numpy's temporaries, large for a speed
window against polygons, and its per-call overhead on small arrays.

``cache=True`` keeps the compiled code beside this file (``__pycache__``), so that bench
workers and later runs load it instead of compiling again.
"""

from __future__ import annotations

import math

import numpy as np

try:
    import numba
except ImportError:  # the numpy kernels run instead
    numba = None

circle_clearance = polygon_clearance = sightline_depth = open_clearance = near_mask = heading_toward = None
choose = None

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

    @_inline
    def _block_sum(a, lo, n):
        """numpy's sum of a[lo:lo + n] for n <= 128: 8 accumulators, then the rest in order."""
        if n < 8:
            res = -0.0
            for i in range(lo, lo + n):
                res += a[i]
            return res
        r = a[lo:lo + 8].copy()
        i = 8
        while i < n - (n % 8):
            for j in range(8):
                r[j] += a[lo + i + j]
            i += 8
        res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
        while i < n:
            res += a[lo + i]
            i += 1
        return res

    @_jit
    def _pairwise_sum(a, lo, n):
        """numpy's pairwise summation of a[lo:lo + n]: blocks of <= 128, halves (the first a
        multiple of 8) added pairwise. numpy recurses; here explicit stacks do (a recursive version
        segfaulted in a process that loaded it from numba's cache)."""
        if n <= 128:
            return _block_sum(a, lo, n)
        seg_lo, seg_n = np.empty(64, np.int64), np.empty(64, np.int64)
        phase, left = np.zeros(64, np.int64), np.empty(64)
        depth, ret = 0, 0.0
        seg_lo[0], seg_n[0] = lo, n
        while True:
            m = seg_n[depth]
            half = m // 2 - (m // 2) % 8
            if phase[depth] == 0 and m <= 128:  # a leaf: its sum goes to the parent
                ret = _block_sum(a, seg_lo[depth], m)
                depth -= 1
            elif phase[depth] == 0:  # descend into the first half
                phase[depth] = 1
                depth += 1
                seg_lo[depth], seg_n[depth], phase[depth] = seg_lo[depth - 1], half, 0
                continue
            elif phase[depth] == 1:  # the first half is summed: descend into the second
                left[depth] = ret
                phase[depth] = 2
                depth += 1
                seg_lo[depth], seg_n[depth], phase[depth] = seg_lo[depth - 1] + half, m - half, 0
                continue
            else:  # both halves summed
                ret = left[depth] + ret
                depth -= 1
            if depth < 0:
                return ret

    @_jit
    def _legal_sum(critic, legal, everyone, buf):
        """critic.sum() when everyone is legal, else critic[legal].sum(), as numpy sums them."""
        if everyone:
            return 0.0 + _pairwise_sum(critic, 0, len(critic))
        n = 0
        for i in range(len(critic)):
            if legal[i]:
                buf[n] = critic[i]
                n += 1
        return 0.0 + _pairwise_sum(buf, 0, n)

    @_jit
    def _add_term(total, started, critic, scale, saturated, sat_value):
        """total (+)= critic * scale (a saturated critic is the constant sat_value * scale)."""
        for i in range(len(total)):
            term = sat_value * scale if saturated else critic[i] * scale
            total[i] = total[i] + term if started else term

    @_jit
    def choose(legal, yaw_rates, turn_error, w, heading, distance, saturated, sat_value, sat_sums,  # noqa: F811
               sightline, has_s, slope, speed, has_v, fixed, cap_m):
        """The turn-around preference, the weighted sum and the best rollout in one pass:
        evaluate.choose's numpy path (commit_turn, evaluate, argmax). ``w``: (w_h, w_d, w_s, w_v);
        ``turn_error``: the goal's bearing off the nose when the preference applies, else NaN.
        Returns (best, its total, how many are legal)."""
        n_s = len(legal)
        ok = legal.copy()
        if not np.isnan(turn_error):
            any_toward = False
            for i in range(n_s):
                if legal[i] and yaw_rates[i] * turn_error >= 0.0:
                    any_toward = True
            if any_toward:
                for i in range(n_s):
                    ok[i] = legal[i] and yaw_rates[i] * turn_error >= 0.0
        n_legal = 0
        for i in range(n_s):
            n_legal += ok[i]
        everyone = n_legal == n_s
        total = np.zeros(n_s)
        if fixed:
            _add_term(total, False, heading, w[0] / 180.0, False, 0.0)
            if w[1] != 0.0 and sat_value > 0.0:
                _add_term(total, True, distance, w[1] / sat_value, False, 0.0)
            if has_s and w[2] != 0.0:
                _add_term(total, True, sightline, w[2] / cap_m, False, 0.0)
            if has_v and w[3] != 0.0:
                _add_term(total, True, speed, w[3], False, 0.0)
        else:
            buf = np.empty(n_s)
            started = False
            for k in range(4):
                if w[k] == 0.0 or (k == 2 and not has_s) or (k == 3 and not has_v):
                    continue
                critic = heading if k == 0 else distance if k == 1 else sightline if k == 2 else speed
                if k == 2 and slope:  # sums need non-negative terms
                    critic = critic + cap_m
                if k == 1 and saturated:
                    norm = sat_sums[n_s if everyone else n_legal]
                else:
                    norm = _legal_sum(critic, ok, everyone, buf)
                if norm > 0.0:
                    _add_term(total, started, critic, w[k] / norm, k == 1 and saturated, sat_value)
                    started = True
        best = -1
        for i in range(n_s):
            if not everyone and not ok[i]:
                total[i] = -np.inf
            v = total[i]
            if best < 0 or np.isnan(v) and not np.isnan(total[best]) or v > total[best]:
                best = i
        return best, total[best], n_legal
