"""Routes with arrival times: where a vehicle is planned to be, and how fast it should go, at t.

A :class:`TimedRoute` is a polyline whose vertices carry sim times (s, from the common mission
start). Position is linear in time between vertices and held before the first and after the last,
so a vertex repeated at two times is a wait. Every query is vectorised over arrays of times (and
positions), so a dynamic window can score a whole batch of rollouts against the plan at once:

    route = forecast("a", sparse_xy, speed_m_s=10.0, hold_s=75.0)   # cruise after a hold
    route.planned_position_at(t)           # (..., 2) ENU metres
    route.planned_speed_at(t)              # (...,) m/s of the plan itself (0 while waiting)
    route.target_speed_at(xy, t, v_max)    # (...,) m/s that brings a vehicle at xy back onto it
    route.is_waiting_at(t)                 # (...,) bool: the plan holds here (a scheduled wait)
"""

from __future__ import annotations

from bisect import bisect_left, bisect_right
from dataclasses import dataclass, fields

import numpy as np

from companion.planning.errors import PlanningError
from companion.planning.timed_route_jit import first_lead_over, interp_in, latest_near, progress_near, schedule_in

_WAIT_SPEED_M_S = 1e-6  # slower than this, a planned segment is a wait


@dataclass(frozen=True, eq=False)
class TimedRoute:
    """One vehicle's planned motion: ``xy_enu_m`` (N, 2) reached at ``t_s`` (N,), non-decreasing."""

    vehicle: str
    t_s: np.ndarray
    xy_enu_m: np.ndarray

    def __post_init__(self) -> None:
        t = np.array(self.t_s, dtype=float).ravel()
        xy = np.array(self.xy_enu_m, dtype=float).reshape(-1, 2)
        if len(t) != len(xy) or len(t) == 0:
            raise PlanningError(f"timed route of {self.vehicle!r}: {len(t)} times for {len(xy)} points")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(xy))) or np.any(np.diff(t) < 0):
            raise PlanningError(f"timed route of {self.vehicle!r}: times must be finite and non-decreasing")
        along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
        # Per segment, computed once: every tick reads them (the flight asks a few times a tick).
        start, d = xy[:-1], np.diff(xy, axis=0)
        len2 = np.einsum("ij,ij->i", d, d)
        dt = np.diff(t)
        speed = np.where(dt > 0, np.hypot(*d.T) / np.where(dt > 0, dt, 1.0), 0.0)
        for name, a in (("t_s", t), ("xy_enu_m", xy), ("_along_m", along), ("_start", start), ("_d", d),
                        ("_len2", len2), ("_len2_div", np.where(len2 > 0, len2, 1.0)), ("_len", np.sqrt(len2)),
                        ("_speed", speed), ("_moving", dt > 0), ("_span_div", np.where(dt > 0, dt, 1.0))):
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        last = np.flatnonzero(np.any(xy != xy[-1], axis=1))
        object.__setattr__(self, "_arrival_s", float(t[last[-1] + 1]) if last.size else float(t[0]))
        object.__setattr__(self, "_last_feet", [None])  # see _feet
        object.__setattr__(self, "_t_list", t.tolist())  # for scalar bisections (every tick)
        object.__setattr__(self, "_along_list", along.tolist())
        object.__setattr__(self, "_last_progress", {})  # (x, y, near_along_m) -> (along, off): a tick asks twice

    def __reduce__(self):
        # Rebuilt when unpickled (a plan made in a child process, companion.app.offload): its arrays
        # read-only again. Unpickled as they were, they come back writeable, another type to the
        # compiled queries, which compiled again at the flight's first tick: 1.4 s of wall time on a
        # cold cache, and the vehicles departed on a pose 5-25 s of sim old.
        return type(self), tuple(getattr(self, f.name) for f in fields(self))

    @property
    def path_xy(self) -> np.ndarray:
        """The route's geometry (K, 2): its points without the repeats of a wait."""
        moved = np.concatenate([[True], np.any(np.diff(self.xy_enu_m, axis=0) != 0, axis=1)])
        return self.xy_enu_m[moved]

    @property
    def departure_s(self) -> float:
        """When the vehicle first leaves its start point (after any hold)."""
        moved = np.flatnonzero(np.any(self.xy_enu_m != self.xy_enu_m[0], axis=1))
        return float(self.t_s[moved[0] - 1]) if moved.size else float(self.t_s[-1])

    @property
    def arrival_s(self) -> float:
        """When the vehicle reaches its last point."""
        return self._arrival_s

    @property
    def length_m(self) -> float:
        return float(np.hypot(*np.diff(self.xy_enu_m, axis=0).T).sum()) if len(self.t_s) > 1 else 0.0

    @property
    def wait_s(self) -> float:
        """Total planned waiting between departure and arrival (holds before departure excluded)."""
        dt, v = self._segments()
        t0, t1 = self.t_s[:-1], self.t_s[1:]
        inside = (t0 >= self.departure_s) & (t1 <= self.arrival_s)
        return float(dt[inside & (v < _WAIT_SPEED_M_S)].sum())

    def _segments(self) -> tuple[np.ndarray, np.ndarray]:
        return np.diff(self.t_s), self._speed

    def _segment_index(self, t: np.ndarray) -> np.ndarray:
        """Index i of the segment [t_i, t_i+1] holding each t (clipped to the ends)."""
        if len(self.t_s) < 2:
            return np.zeros(t.shape, dtype=int)
        return np.minimum(np.maximum(np.searchsorted(self.t_s, t, side="right") - 1, 0), len(self.t_s) - 2)

    def planned_position_at(self, t_s: np.ndarray | float) -> np.ndarray:
        """Planned positions (..., 2) at times ``t_s`` (...,)."""
        t = np.asarray(t_s, dtype=float)
        if len(self.t_s) == 1:
            return np.broadcast_to(self.xy_enu_m[0], t.shape + (2,)).copy()
        i = self._segment_index(t)
        u = np.where(self._moving[i], (t - self.t_s[i]) / self._span_div[i], 1.0)
        return self._start[i] + self._d[i] * np.minimum(np.maximum(u, 0.0), 1.0)[..., None]

    def latest_near_s(self, xy_enu_m, t0_s: float, offsets_s: np.ndarray, tolerance_m: float) -> float:
        """Of the times ``t0_s + offsets_s`` (non-decreasing), the latest at which the plan is
        within ``tolerance_m`` of its least distance to ``xy_enu_m`` over those times: the latest
        plan time a vehicle seen there is consistent with (:class:`.clocks.ScheduleClock`).
        Compiled when numba is installed (:mod:`.timed_route_jit`, the same bits)."""
        x, y = float(xy_enu_m[0]), float(xy_enu_m[1])
        if latest_near is not None and len(self.t_s) > 1:
            return float(latest_near(self.t_s, self._start, self._d, self._moving, self._span_div, float(t0_s),
                                     offsets_s, x, y, float(tolerance_m)))
        times = t0_s + offsets_s
        p = self.planned_position_at(times)
        d = np.hypot(p[:, 0] - x, p[:, 1] - y)
        return float(times[np.flatnonzero(d <= d.min() + tolerance_m)[-1]])

    def planned_speed_at(self, t_s: np.ndarray | float) -> np.ndarray:
        """Speed (...,) of the plan itself at ``t_s``: 0 while waiting and outside the route."""
        if isinstance(t_s, float) and len(self.t_s) > 1:  # one time (every tick): no arrays
            if not self._t_list[0] <= t_s < self._t_list[-1]:
                return np.float64(0.0)
            i = bisect_right(self._t_list, t_s) - 1
            return self._speed[min(max(i, 0), len(self.t_s) - 2)]
        t = np.asarray(t_s, dtype=float)
        if len(self.t_s) == 1:
            return np.zeros(t.shape)
        inside = (t >= self.t_s[0]) & (t < self.t_s[-1])
        return np.where(inside, self._speed[self._segment_index(t)], 0.0)

    def is_waiting_at(self, t_s: np.ndarray | float) -> np.ndarray:
        """Whether the plan holds the vehicle still at ``t_s`` (before departure included, after
        arrival excluded: an arrived vehicle is done, not waiting)."""
        if isinstance(t_s, float):  # one time: the cheap test first
            return np.bool_(t_s < self._arrival_s and self.planned_speed_at(t_s) < _WAIT_SPEED_M_S)
        t = np.asarray(t_s, dtype=float)
        return (self.planned_speed_at(t) < _WAIT_SPEED_M_S) & (t < self.arrival_s)

    def planned_along_at(self, t_s: np.ndarray | float) -> np.ndarray:
        """How far along the route (m, ...) the plan is at ``t_s``."""
        if isinstance(t_s, float) and len(self.t_s) > 1:  # one time (every tick): no arrays
            return np.float64(interp_one(t_s, self._t_list, self._along_list))
        return np.interp(np.asarray(t_s, dtype=float), self.t_s, self._along_m)

    def progress_at(self, xy_enu_m: np.ndarray, near_along_m: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(along, off) (...,) m: how far along the route the nearest route point to each of
        ``xy_enu_m`` (..., 2) is, and how far the position is from it. ``near_along_m``: where
        along the route the vehicle was last (see :func:`progress_window`): only the route within
        that window counts, so a path that passes near itself (out and back round a shadow, a wait
        beside a later leg) cannot throw the vehicle hundreds of metres ahead or behind."""
        point = np.asarray(xy_enu_m, dtype=float)
        if point.shape == (2,):
            return self.progress_of(float(point[0]), float(point[1]), near_along_m)
        return self._progress(point[..., None, :], near_along_m)

    def progress_of(self, x_m: float, y_m: float, near_along_m: float | None = None) -> tuple[np.float64, np.float64]:
        """:meth:`progress_at` of one position (x, y): what every tick asks (the re-plan's
        watch; the planner's own asks :meth:`schedule_of`). One compiled call, its window
        included, when numba is installed; else the last few answers are kept."""
        if progress_near is not None and len(self.t_s) > 1:
            along, off = progress_near(self._start, self._d, self._len2_div, self._along_m, self._len, x_m, y_m,
                                       np.nan if near_along_m is None else near_along_m, PROGRESS_BACK_M,
                                       PROGRESS_AHEAD_M)
            return np.float64(along), np.float64(off)
        key = (x_m, y_m, near_along_m)
        found = self._last_progress.get(key)
        if found is None:
            found = self._progress(np.array([[x_m, y_m]]), near_along_m)
            if len(self._last_progress) >= 4:
                self._last_progress.clear()
            self._last_progress[key] = found
        return found

    def _window_segments(self, near_along_m: float | None) -> tuple[int, int]:
        """The segments ``lo_i`` to ``hi_i`` that the progress window of ``near_along_m`` reaches
        into (every segment without one, or when none does): a contiguous run, found by bisection."""
        lo_i, hi_i = 0, len(self._len2)
        if near_along_m is not None:
            lo, hi = progress_window(near_along_m)
            along = self._along_list  # a scalar bisection on a list: no numpy call
            first = bisect_left(along, lo, 1) - 1
            end = bisect_right(along, hi, 0, len(along) - 1)
            if first < end:  # some segment reaches into the window; else the whole route counts
                lo_i, hi_i = first, end
        return lo_i, hi_i

    def _progress(self, xy: np.ndarray, near_along_m: float | None) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`progress_at` of ``xy`` (..., 1, 2), over the segments in the window only: the
        window is a contiguous run of segments (``_along_m`` never decreases), found by bisection."""
        if len(self.t_s) == 1:
            return np.zeros(xy.shape[:-2]), np.hypot(*np.moveaxis(xy[..., 0, :] - self.xy_enu_m[0], -1, 0))
        lo_i, hi_i = self._window_segments(near_along_m)
        if xy.shape == (1, 2):  # one position without the compiled kernel: its feet on the segments near
            u, dist, first = self._feet(xy, lo_i, hi_i)
            i = lo_i + int(np.argmin(dist[lo_i - first:hi_i - first]))
            return self._along_m[i] + u[i - first] * self._len[i], dist[i - first]
        a, d, len2 = self._start[lo_i:hi_i], self._d[lo_i:hi_i], self._len2_div[lo_i:hi_i]
        u = np.clip(np.einsum("...ij,ij->...i", xy - a, d) / len2, 0.0, 1.0)
        dist = np.hypot(*np.moveaxis(a + d * u[..., None] - xy, -1, 0))
        i = np.argmin(dist, axis=-1)[..., None]
        along = self._along_m[lo_i:hi_i] + u * self._len[lo_i:hi_i]
        return np.take_along_axis(along, i, -1)[..., 0], np.take_along_axis(dist, i, -1)[..., 0]

    def _feet(self, xy: np.ndarray, lo_i: int, hi_i: int) -> tuple[np.ndarray, np.ndarray, int]:
        """For one position ``xy`` (1, 2) and the segments ``lo_i`` to ``hi_i`` (at least): the
        fraction along each segment of its point nearest ``xy``, its distance from there, and
        the first segment they start at. A tick asks for the progress of one position two or
        three times, each over its own window a few metres on (the schedule clocks, the
        planner's progress, its target speed): the last position's are kept, worked out a few
        segments either side of the window asked, and each window reads its slice. Elementwise,
        so a slice holds the bits a window of its own would."""
        key = (float(xy[0, 0]), float(xy[0, 1]))
        last = self._last_feet[0]  # read and replaced whole: a worker thread may ask meanwhile
        if last is None or last[0] != key or lo_i < last[1] or hi_i > last[2]:
            lo, hi = max(lo_i - _FEET_BACK, 0), min(hi_i + _FEET_AHEAD, len(self._len2))
            a, d = self._start[lo:hi], self._d[lo:hi]
            u = np.minimum(np.maximum(np.einsum("ij,ij->i", xy - a, d) / self._len2_div[lo:hi], 0.0), 1.0)
            near = a + d * u[:, None] - xy
            last = self._last_feet[0] = (key, lo, hi, u, np.hypot(near[:, 0], near[:, 1]))
        return last[3], last[4], last[1]

    def lead_m(self, xy_enu_m: np.ndarray, t_s: np.ndarray | float, near_along_m: float | None = None) -> np.ndarray:
        """How far (m, ...) a vehicle at ``xy_enu_m`` is ahead of the plan at ``t_s`` along the
        route (negative: it lags); ``near_along_m`` as for :meth:`progress_at`."""
        along, _ = self.progress_at(xy_enu_m, near_along_m)
        return along - self.planned_along_at(t_s)

    def target_speed_at(self, xy_enu_m: np.ndarray, t_s: np.ndarray | float, max_speed_m_s: float,
                        lookahead_s: float = 5.0, near_along_m: float | None = None) -> np.ndarray:
        """The speed (...,) that takes a vehicle at ``xy_enu_m`` (..., 2) to where the plan will be
        ``lookahead_s`` later, measured along the route (plus its distance off it), capped at
        ``max_speed_m_s``: cruise when it lags, slower when it is ahead, 0 when it is as far along
        as the plan will be ``lookahead_s`` later (a scheduled wait, or running early: it waits
        for the plan, however far ahead it is). ``near_along_m`` as for :meth:`progress_at`."""
        along, off = self.progress_at(xy_enu_m, near_along_m)
        if isinstance(t_s, float) and np.ndim(along) == 0:  # one position at one time
            return self._target_speed(along, off, t_s, max_speed_m_s, lookahead_s)
        gap = self.planned_along_at(np.asarray(t_s, dtype=float) + lookahead_s) - along
        return np.where(gap > 0, np.minimum(np.hypot(gap, off) / lookahead_s, max_speed_m_s), 0.0)

    def target_speed_of(self, x_m: float, y_m: float, t_s: float, max_speed_m_s: float, lookahead_s: float = 5.0,
                        near_along_m: float | None = None) -> np.float64:
        """:meth:`target_speed_at` of one position at one time: what every tick asks."""
        along, off = self.progress_of(x_m, y_m, near_along_m)
        return self._target_speed(along, off, float(t_s), max_speed_m_s, lookahead_s)

    def schedule_of(self, x_m: float, y_m: float, t_s: float, max_speed_m_s: float, near_along_m: float | None,
                    lookahead_s: float = 5.0) -> tuple[float, float, float, bool]:
        """A tick's whole schedule for a vehicle at (x, y) at plan time ``t_s``, last
        ``near_along_m`` along (None: unknown): (along, target speed, lead, waiting), where
        ``along`` is :meth:`progress_of`'s, the target speed :meth:`target_speed_of`'s from
        there, the lead ``along`` less :meth:`planned_along_at` ``t_s``, and waiting
        :meth:`is_waiting_at`'s. One compiled call when numba is installed (the same bits)."""
        if schedule_in is not None and len(self.t_s) > 1:
            along, speed, lead, waiting = schedule_in(
                self.t_s, self._along_m, self._speed, self._start, self._d, self._len2_div, self._len,
                self._arrival_s, x_m, y_m, float(t_s), max_speed_m_s, lookahead_s,
                np.nan if near_along_m is None else near_along_m, PROGRESS_BACK_M, PROGRESS_AHEAD_M, _WAIT_SPEED_M_S)
            return along, speed, lead, waiting
        along = float(self.progress_of(x_m, y_m, near_along_m)[0])
        speed = float(self.target_speed_of(x_m, y_m, t_s, max_speed_m_s, lookahead_s, along))
        return along, speed, along - float(self.planned_along_at(t_s)), bool(self.is_waiting_at(t_s))

    def first_lead_over(self, xs_m: np.ndarray, ys_m: np.ndarray, ts_s: np.ndarray, limit_m: float) -> int | None:
        """The first k at which a vehicle at (``xs_m[k]``, ``ys_m[k]``) at plan time ``ts_s[k]``,
        read tick after tick as :meth:`schedule_of` reads it (each near the last one's progress),
        leads the plan by more than ``limit_m``; None when it never does. One compiled call
        when numba is installed (the same bits)."""
        if first_lead_over is not None and len(self.t_s) > 1:
            k = first_lead_over(self.t_s, self._along_m, self._start, self._d, self._len2_div, self._len,
                                np.asarray(xs_m, dtype=float), np.asarray(ys_m, dtype=float),
                                np.asarray(ts_s, dtype=float), PROGRESS_BACK_M, PROGRESS_AHEAD_M, float(limit_m))
            return None if k < 0 else int(k)
        along = None
        for k, (x, y, t) in enumerate(zip(xs_m, ys_m, ts_s)):
            along, _, lead_m, _ = self.schedule_of(float(x), float(y), float(t), 0.0, along)
            if lead_m > limit_m:
                return k
        return None

    def _target_speed(self, along: np.float64, off: np.float64, t_s: float, max_speed_m_s: float,
                      lookahead_s: float) -> np.float64:
        gap = self.planned_along_at(t_s + lookahead_s) - along
        if not gap > 0:
            return np.float64(0.0)
        speed = np.hypot(gap, off) / lookahead_s  # never NaN, never -0.0: min picks what np.minimum picks
        return np.float64(speed if speed < max_speed_m_s else max_speed_m_s)


_FEET_BACK, _FEET_AHEAD = 4, 12  # segments beyond a progress window its position's feet cover (see _feet)
PROGRESS_BACK_M, PROGRESS_AHEAD_M = 30.0, 60.0  # a vehicle flies ~5 m a tick; see progress_window


def interp_one(x: float, xp: list[float], fp: list[float]) -> float:
    """``np.interp(x, xp, fp)`` of one finite ``x`` on lists (two points or more), bit for bit:
    numpy's own steps (the held ends, then :func:`.timed_route_jit.interp_in`) in plain floats,
    without numpy's per-call cost."""
    if x < xp[0]:
        return fp[0]
    last = len(xp) - 1
    if x >= xp[last]:
        return fp[last]
    return interp_in(x, xp, fp, bisect_right(xp, x) - 1)


def progress_window(near_along_m: float) -> tuple[float, float]:
    """The stretch of a route (m along it) a vehicle last seen ``near_along_m`` along can be on
    a tick later: a little behind (it drifts back while it waits, or turns), more ahead."""
    return near_along_m - PROGRESS_BACK_M, near_along_m + PROGRESS_AHEAD_M
