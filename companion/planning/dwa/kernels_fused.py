"""Fused compiled (numba) tick kernels, re-exported by :mod:`.kernels` (listed in its ``_NAMES``,
swapped out in ``numpy_only``): each is several kernels of :mod:`.kernels` and :mod:`.kernels_tick`
called in one compiled pass, so that a tick crosses from Python into compiled code fewer times.
On this machine a compiled call costs a few microseconds before it does anything (numba types
every argument), and the paper window's tick made about a dozen of them.

- ``obstacle_pass``: the clearances of every rollout point to the culled obstacles (circles, then
  polygons), the obstacle rule per point, the distance critic and the rule per rollout
  (:func:`.geometry.inflated_clearance`, :func:`.distance.obstacle_and_distance` and
  :func:`.legality.legal_rollouts` for the one rule);
- ``pick``: the heading critic toward one target, the choice and the chosen rollout's command
  values (:func:`.heading.heading_from_ends`' single path, :func:`.evaluate.choose` and
  :func:`.evaluate.command_for`).

They call the very kernels they fuse, so they compute the same numbers:
``tests/planning/test_kernels_fused.py`` checks them bit for bit against the numpy code. None
without numba.
"""

from __future__ import annotations

import numpy as np

from companion.planning.dwa import kernels, kernels_tick  # kernels: imported at its end, its kernels defined

try:
    import numba
except ImportError:  # the numpy code runs instead
    numba = None

obstacle_pass = pick = None

if numba is not None and kernels.circle_clearance is not None:
    _jit = numba.njit(cache=True, nogil=True, error_model="numpy")
    _circle_clearance, _polygon_clearance = kernels.circle_clearance, kernels.polygon_clearance
    _heading_toward, _choose, _obstacle_terms = kernels.heading_toward, kernels.choose, kernels_tick.obstacle_terms

    @_jit
    def obstacle_pass(px, py, t_s, c_xy, c_vel, c_r, c_m, p_a, p_b, p_d, p_inv_len2, p_dx_per_dy, p_vel,  # noqa: F811
                      p_m, n_k, saturation):
        """Clearances (O, N) of the N = R * n_k points (px, py) at t_s to the circles and
        polygons, the obstacle rule per point (N,), the distance critic (R,) and whether each
        rollout obeys the rule at every point after the pose (R,)."""
        n_c, n_p = len(c_r), p_a.shape[0]
        clear = np.empty((n_c + n_p, len(px)))
        if n_c:
            _circle_clearance(px, py, t_s, c_xy, c_vel, c_r, c_m, clear, 0)
        if n_p:
            _polygon_clearance(px, py, t_s, p_a, p_b, p_d, p_inv_len2, p_dx_per_dy, p_vel, p_m, clear, n_c)
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
        return clear, ok, distance, legal

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
