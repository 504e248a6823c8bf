"""More compiled (numba) tick kernels, re-exported by :mod:`.kernels` (which lists them in its
``_NAMES`` and swaps them out in ``numpy_only``): the heading critic toward a window of goals,
the obstacle rule with the distance critic from the clearances, and the sight lines' frame (the
sightline critic's operands before its matrix product). None without numba.

As in :mod:`.kernels`, each does per element exactly the floating-point operations of its numpy
twin (:func:`.heading.heading_from_ends`, :func:`.legality.obstacle_ok` and
:func:`.distance.obstacle_and_distance`, :func:`.sightline._sightline_scores`), in the same order; only minima, comparisons and first indices
are reordered, which are exact (up to the sign of a zero minimum, which only reaches comparisons
and a np.maximum with +0.0 that returns +0.0 either way). ``tests/planning/test_kernels_tick.py`` checks them bit for bit.
"""

from __future__ import annotations

import numpy as np

try:
    import numba
except ImportError:  # the numpy code runs instead
    numba = None

heading_goals = obstacle_terms = sight_frame = None

if numba is not None:
    _jit = numba.njit(cache=True, nogil=True, error_model="numpy")

    @_jit
    def heading_goals(ex, ey, final_heading, px, py, nodes, prev, radius2, ends_at_station,  # noqa: F811
                      soonest_deg):
        """heading_from_ends' window path: each rollout (S, K + 1) scored toward the first goal of
        ``nodes`` (G, 2) it does not reach (a point within radius2 of it, or its prediction point
        past it, from ``prev``); an arriving rollout (``ends_at_station``) scores 180 less
        soonest_deg times the fraction of the horizon it takes to get inside the station's radius."""
        n_s, n_k = px.shape
        count = len(nodes)
        out = np.empty(n_s)
        for i in range(n_s):
            n = count
            for j in range(count):
                gx, gy = nodes[j, 0], nodes[j, 1]
                near2 = np.inf
                for k in range(n_k):
                    dx = px[i, k] - gx
                    dy = py[i, k] - gy
                    d2 = dx * dx + dy * dy
                    if d2 < near2:
                        near2 = d2
                reached = near2 <= radius2[j]
                if not reached and not (ends_at_station and j == count - 1):
                    reached = (ex[i] - gx) * (gx - prev[j, 0]) + (ey[i] - gy) * (gy - prev[j, 1]) > 0.0
                if not reached:
                    n = j
                    break
            if ends_at_station and n == count:
                arrive = 180.0
                if soonest_deg > 0.0:
                    sx, sy = nodes[count - 1, 0], nodes[count - 1, 1]
                    first = 0
                    for k in range(n_k):
                        dx = px[i, k] - sx
                        dy = py[i, k] - sy
                        if dx * dx + dy * dy <= radius2[count - 1]:
                            first = k
                            break
                    arrive -= soonest_deg * first / (n_k - 1)
                out[i] = arrive
                continue
            t = min(n, count - 1)
            bearing = np.arctan2(nodes[t, 1] - ey[i], nodes[t, 0] - ex[i])
            deviation = abs((final_heading[i] - bearing + np.pi) % (2.0 * np.pi) - np.pi)
            out[i] = 180.0 - np.degrees(deviation)
        return out

    @_jit
    def obstacle_terms(clear, n_k, saturation):  # noqa: F811
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

    @_jit
    def sight_frame(ex, ey, qx, qy, t_s, c_xy, c_vel, c_r, p_a, p_vel, p_d, keep, masked):  # noqa: F811
        """_sightline_scores' operands for sight segments (ex, ey) -> q, over the obstacles
        ``keep`` marks (circles, then polygons; all when not ``masked``): the rows (the kept
        circle centres, polygon vertices, each predicted to t_s and relative to q, then the edge
        vectors) (R, 2), the basis [unit left normals | segment vectors] (2, 2S), the squared
        lengths (S,), the kept circles' radii and how many polygons are kept."""
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
