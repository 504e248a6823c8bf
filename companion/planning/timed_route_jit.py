"""The per-tick queries of a :class:`.TimedRoute` compiled (numba), when numba is installed (the
``fast`` extra): :meth:`.TimedRoute.latest_near_s` (``latest_near``) and the progress of one
position (``progress_in``); None otherwise, and the numpy queries run.

Each schedule clock asks the first for every vehicle above it, every tick
(:mod:`.coordination.clocks`), and each timed vehicle the second two or three times a tick: as
numpy, some ten to twenty calls on small arrays each; compiled, one. Each does per element
exactly the floating-point operations of its numpy twin, in the same order (the times in order,
so the segment index is a cursor instead of a bisection; the first least distance, as argmin
takes it), and calls the C library's ``hypot`` as numpy does, so both return the same bits:
``tests/planning/test_timed_route_jit.py`` holds them to it.
"""

from __future__ import annotations

import numpy as np

try:
    import numba
except ImportError:  # the numpy query runs instead
    numba = None

if numba is None:
    latest_near = progress_in = None
else:
    @numba.njit(cache=True, nogil=True, error_model="numpy")
    def latest_near(t_s, start, d, moving, span_div, t0_s, offsets_s, x_m, y_m, tolerance_m):  # pragma: no cover
        """The latest of the times t0_s + offsets_s (non-decreasing) at which the route (two
        points or more) is planned within ``tolerance_m`` of its least distance to (x, y)
        over those times."""
        last = len(t_s) - 2
        m = len(offsets_s)
        times = np.empty(m)
        dist = np.empty(m)
        j = 0
        least = np.inf
        for k in range(m):
            t = t0_s + offsets_s[k]
            while j < last and t_s[j + 1] <= t:
                j += 1
            u = (t - t_s[j]) / span_div[j] if moving[j] else 1.0
            u = min(max(u, 0.0), 1.0)
            dist[k] = np.hypot(start[j, 0] + d[j, 0] * u - x_m, start[j, 1] + d[j, 1] * u - y_m)
            times[k] = t
            least = min(least, dist[k])
        limit = least + tolerance_m
        for k in range(m - 1, -1, -1):
            if dist[k] <= limit:
                return times[k]
        return times[m - 1]

    @numba.njit(cache=True, nogil=True, error_model="numpy")
    def progress_in(start, d, len2_div, along_m, seg_len, x_m, y_m, lo, hi):  # pragma: no cover
        """(along, off): the point of segments ``lo`` to ``hi`` (at least one) nearest (x, y),
        how far along the route it is and how far (x, y) is from it."""
        best = np.inf
        at = lo
        at_u = 0.0
        for i in range(lo, hi):
            u = ((x_m - start[i, 0]) * d[i, 0] + (y_m - start[i, 1]) * d[i, 1]) / len2_div[i]
            u = min(max(u, 0.0), 1.0)
            dist = np.hypot(start[i, 0] + d[i, 0] * u - x_m, start[i, 1] + d[i, 1] * u - y_m)
            if dist < best:
                best, at, at_u = dist, i, u
        return along_m[at] + at_u * seg_len[at], best
