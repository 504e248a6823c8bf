"""Fused compiled (numba) tick kernels, re-exported by :mod:`.kernels` (listed in its ``_NAMES``,
swapped out in ``numpy_only``): each is several kernels of :mod:`.kernels_point` and :mod:`.kernels_tick`
called in one compiled pass, so that a tick crosses from Python into compiled code fewer times.
On this machine a compiled call costs a few microseconds before it does anything (numba types
every argument), and the paper window's tick made about a dozen of them.

- ``obstacle_pass``: the clearances of the rollout points to the culled obstacles (circles, then
  polygons; only where they can matter), the obstacle rule per point, the distance critic and
  the rule per rollout (:func:`.geometry.inflated_clearance`, :func:`.distance.obstacle_and_distance`
  and :func:`.legality.legal_rollouts` for the one rule);
- ``pick``: the heading critic toward one target, the choice and the chosen rollout's command
  values (:func:`.heading.heading_from_ends`' single path, :func:`.evaluate.choose` and
  :func:`.evaluate.command_for`).

They do the operations of the kernels they fuse, or call them, so they compute the same numbers:
``tests/planning/test_kernels_fused.py`` checks them bit for bit against the numpy code. None
without numba.
"""

from __future__ import annotations

import numpy as np

from companion.planning.dwa import kernels_point, kernels_tick

try:
    import numba
except ImportError:  # the numpy code runs instead
    numba = None

obstacle_pass = pick = None

if numba is not None and kernels_point.circle_clearance is not None:
    _jit = numba.njit(cache=True, nogil=True, error_model="numpy")
    _polygon_point = kernels_point._polygon_point
    _heading_toward, _choose, _obstacle_terms = kernels_point.heading_toward, kernels_point.choose, kernels_tick.obstacle_terms

    @_jit
    def obstacle_pass(px, py, t_s, c_xy, c_vel, c_r, c_m, p_a, p_b, p_d, p_inv_len2, p_dx_per_dy, p_vel,  # noqa: F811
                      p_m, p_centre, p_bound, keep, n_k, saturation):
        """Clearances (O, N) of the N = R * n_k points (px, py) at t_s to the O circles and
        polygons that ``keep`` marks (circles, then polygons: the culled subset's rows), the
        obstacle rule per point (N,), the distance critic (R,), whether each rollout obeys the
        rule at every point after the pose (R,), and whether every clearance is exact.

        A point farther from an obstacle's bounding disc (a polygon's ``p_centre``, ``p_bound``)
        than the saturation plus 1 m has a clearance above the saturation: it can neither break
        the rule nor set the distance critic, so its clearance is not worked out (+inf stands for
        it, and the rule and critic come out the same). The caller works the clearances out in
        full when it reads them (the escape, with no legal rollout)."""
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
            for n in range(len(px)):  # kernels_point.circle_clearance's operations, where needed
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
            row = clear[k]
            k += 1
            for n in range(len(px)):  # kernels_point.polygon_clearance's operations, where needed
                qx = px[n] - vx * t_s[n]
                qy = py[n] - vy * t_s[n]
                dx = qx - p_centre[p, 0]
                dy = qy - p_centre[p, 1]
                if dx * dx + dy * dy > lim2:
                    row[n] = np.inf
                    exact = False
                else:
                    row[n] = _polygon_point(qx, qy, p, p_a, p_b, p_d, p_inv_len2, p_dx_per_dy) - m
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

    @_jit
    def pick(ex, ey, heading_rad, final_dheading, tx, ty, legal, yaw_rates, speeds, turn_error, w,  # noqa: F811
             distance, saturated, sat_value, sat_sums, sightline, has_s, slope, speed, has_v, fixed, cap_m):
        """The heading critic toward (tx, ty) at the prediction points (ex, ey) with headings
        heading_rad + final_dheading, then the choice; returns the chosen rollout's (yaw rate,
        speed, heading, distance and sightline scores, total, legal count): a Command's fields."""
        final = np.empty(len(ex))
        for i in range(len(ex)):
            final[i] = heading_rad + final_dheading[i]
        heading = _heading_toward(ex, ey, final, tx, ty)
        best, total, n_legal = _choose(legal, yaw_rates, turn_error, w, heading, distance, saturated, sat_value,
                                       sat_sums, sightline, has_s, slope, speed, has_v, fixed, cap_m)
        s = sightline[best] if has_s else 0.0
        return yaw_rates[best], speeds[best], heading[best], distance[best], s, total, n_legal
