"""The per-tick queries of a :class:`.TimedRoute` compiled (numba), when numba is installed (the
``fast`` extra): :meth:`.TimedRoute.latest_near_s` (``latest_near``), the progress of one position
(``progress_near``: its window's segments, then ``progress_in`` over them) and a tick's whole
schedule (``schedule_in``: :meth:`.TimedRoute.schedule_of`); None otherwise, and the numpy and
plain-float queries run.

Each schedule clock asks the first for every vehicle above it, every tick
(:mod:`.coordination.clocks`), the re-plan's watch the second, and each timed vehicle the third
once a tick: as numpy or plain floats, some ten to twenty calls each; compiled, one. Each does
per element exactly the floating-point operations of its numpy twin, in the same order (the
times in order, so past the first time's segment the index is a cursor; the first least
distance, as argmin takes it), and calls the C library's ``hypot`` as numpy does, so both
return the same bits: ``tests/planning/test_timed_route_jit.py`` holds them to it.
"""

from __future__ import annotations

import numpy as np

try:
    import numba
except ImportError:  # the numpy query runs instead
    numba = None


def interp_in(x, xp, fp, j):
    """``np.interp(x, xp, fp)`` of an ``x`` inside ``xp[j]`` to ``xp[j + 1]`` (``xp[j] <= x <
    xp[j + 1]``), numpy's own steps: the exact node, the slope, and the other end when that gives
    NaN. Plain Python, and compiled for :func:`schedule_in`: one source for both."""
    if xp[j] == x:
        return fp[j]
    slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])
    y = slope * (x - xp[j]) + fp[j]
    if y != y:
        y = slope * (x - xp[j + 1]) + fp[j + 1]
        if y != y and fp[j] == fp[j + 1]:
            y = fp[j]
    return y


if numba is None:
    latest_near = progress_in = progress_near = schedule_in = first_lead_over = None
else:
    @numba.njit(cache=True, nogil=True)
    def _bisect_left(a, x, lo, hi):  # pragma: no cover
        """Python's ``bisect_left(a, x, lo, hi)``."""
        while lo < hi:
            mid = (lo + hi) // 2
            if a[mid] < x:
                lo = mid + 1
            else:
                hi = mid
        return lo

    @numba.njit(cache=True, nogil=True)
    def _bisect_right(a, x, lo, hi):  # pragma: no cover
        """Python's ``bisect_right(a, x, lo, hi)``."""
        while lo < hi:
            mid = (lo + hi) // 2
            if x < a[mid]:
                hi = mid
            else:
                lo = mid + 1
        return lo

    @numba.njit(cache=True, nogil=True, error_model="numpy")
    def latest_near(t_s, start, d, moving, span_div, t0_s, offsets_s, x_m, y_m, tolerance_m):  # pragma: no cover
        """The latest of the times t0_s + offsets_s (non-decreasing) at which the route (two
        points or more) is planned within ``tolerance_m`` of its least distance to (x, y)
        over those times."""
        last = len(t_s) - 2
        m = len(offsets_s)
        times = np.empty(m)
        dist = np.empty(m)
        j = 0  # the segment of the first time found by bisection, then a cursor
        if m > 0:
            j = min(max(_bisect_right(t_s, t0_s + offsets_s[0], 0, last + 2) - 1, 0), last)
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

    _interp_in = numba.njit(cache=True, nogil=True, error_model="numpy")(interp_in)

    @numba.njit(cache=True, nogil=True, error_model="numpy")
    def _interp(x, xp, fp):  # pragma: no cover
        """:func:`.timed_route.interp_one` (``np.interp`` of one finite x, two points or more)."""
        last = len(xp) - 1
        if x < xp[0]:
            return fp[0]
        if x >= xp[last]:
            return fp[last]
        return _interp_in(x, xp, fp, _bisect_right(xp, x, 0, last + 1) - 1)

    @numba.njit(cache=True, nogil=True, error_model="numpy")
    def progress_near(start, d, len2_div, along_m, seg_len, x_m, y_m, near, back_m, ahead_m):  # pragma: no cover
        """:meth:`.TimedRoute.progress_of` (NaN ``near``: no window): the window's segments
        (:meth:`.TimedRoute._window_segments`), then ``progress_in`` over them."""
        lo_i, hi_i = 0, len(len2_div)
        if near == near:
            first = _bisect_left(along_m, near - back_m, 1, len(along_m)) - 1
            end = _bisect_right(along_m, near + ahead_m, 0, len(along_m) - 1)
            if first < end:
                lo_i, hi_i = first, end
        return progress_in(start, d, len2_div, along_m, seg_len, x_m, y_m, lo_i, hi_i)

    @numba.njit(cache=True, nogil=True, error_model="numpy")
    def schedule_in(t_s, along_m, speed, start, d, len2_div, seg_len, arrival_s, x_m, y_m, t, max_speed_m_s,
                    lookahead_s, near, back_m, ahead_m, wait_speed_m_s):  # pragma: no cover
        """(along, target speed, lead, waiting) of a vehicle at (x, y) at plan time t, last
        ``near`` along (NaN: unknown): :meth:`.TimedRoute.schedule_of`, step for step."""
        along, _ = progress_near(start, d, len2_div, along_m, seg_len, x_m, y_m, near, back_m, ahead_m)
        along_2, off = progress_near(start, d, len2_div, along_m, seg_len, x_m, y_m, along, back_m, ahead_m)
        gap = _interp(t + lookahead_s, t_s, along_m) - along_2
        target = 0.0
        if gap > 0:
            target = np.hypot(gap, off) / lookahead_s
            target = target if target < max_speed_m_s else max_speed_m_s
        lead = along - _interp(t, t_s, along_m)
        last = len(t_s) - 1
        planned = 0.0
        if t_s[0] <= t < t_s[last]:
            planned = speed[min(max(_bisect_right(t_s, t, 0, last + 1) - 1, 0), last - 1)]
        return along, target, lead, t < arrival_s and planned < wait_speed_m_s

    @numba.njit(cache=True, nogil=True, error_model="numpy")
    def first_lead_over(t_s, along_m, start, d, len2_div, seg_len, xs, ys, ts, back_m, ahead_m,
                        limit_m):  # pragma: no cover
        """:meth:`.TimedRoute.first_lead_over`: each position's lead as ``schedule_in`` reads it,
        near the last one's progress, until one leads by more than ``limit_m``."""
        near = np.nan
        for k in range(len(xs)):
            along, _ = progress_near(start, d, len2_div, along_m, seg_len, xs[k], ys[k], near, back_m, ahead_m)
            if along - _interp(ts[k], t_s, along_m) > limit_m:
                return k
            near = along
        return -1
