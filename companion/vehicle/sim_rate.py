"""How fast a vehicle's sim clock runs against the wall clock, from its stamped telemetry. Pure.

    est = SimRateEstimator(); est.add(arrival_wall_s, stamp_sim_s) ...; est.rate  -> float | None

Every message is stamped when it is sent (sim time) and seen when the event loop gets to it
(wall time). Seen late is the only error there is: a message never arrives before it is sent.
So the points (wall, sim) lie on or below the line of the true clock, and the fresh ones lie on
it: the upper envelope (concave hull) of a window of points follows the clock, and a burst of
late messages (the loop was busy, the link queued them) lies under it and moves it nowhere.

The rate is the envelope's slope between the window's first and third quarter: a burst at the
window's start (the backlog of a stall) or a late last sample cannot set it, as long as it lasts
less than a quarter of the window. Until the window spans ``min_span_s`` the rate is unknown (None).
"""

from __future__ import annotations

from collections import deque

WINDOW_WALL_S = 12.0  # points kept: bursts shorter than a quarter of this cannot move the rate
MIN_SPAN_WALL_S = 2.0  # a rate from fewer wall seconds than this is not given
MIN_GAP_WALL_S = 0.02  # one point per this much wall time: the envelope needs no more
UPDATE_EVERY_WALL_S = 0.25  # the hull is worked out again at most this often (telemetry comes at 100s/s)


def _cross(o: tuple[float, float], a: tuple[float, float], b: tuple[float, float]) -> float:
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


def upper_envelope(points: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """The upper convex hull of points sorted by their first coordinate (Andrew's monotone chain)."""
    hull: list[tuple[float, float]] = []
    for p in points:
        while len(hull) >= 2 and _cross(hull[-2], hull[-1], p) >= 0:
            hull.pop()
        hull.append(p)
    return hull


def envelope_at(hull: list[tuple[float, float]], x: float) -> float:
    """The piecewise-linear envelope's value at ``x`` (within its span)."""
    for (x0, y0), (x1, y1) in zip(hull, hull[1:]):
        if x <= x1:
            return y0 if x1 <= x0 else y0 + (y1 - y0) * (x - x0) / (x1 - x0)
    return hull[-1][1]


class SimRateEstimator:
    """Sim seconds per wall second over a sliding window of (arrival wall, stamp) points."""

    def __init__(self, window_s: float = WINDOW_WALL_S, min_span_s: float = MIN_SPAN_WALL_S):
        self.window_s = window_s
        self.min_span_s = min_span_s
        self._points: deque[tuple[float, float]] = deque()
        self._rate: float | None = None
        self._updated_wall_s = float("-inf")

    @property
    def rate(self) -> float | None:
        return self._rate

    def reset(self) -> None:
        self._points.clear()
        self._rate = None
        self._updated_wall_s = float("-inf")

    def add(self, wall_s: float, sim_s: float) -> None:
        pts = self._points
        if pts and sim_s < pts[-1][1]:
            self.reset()  # the clock went back: the vehicle rebooted
        elif pts and wall_s - pts[-1][0] < MIN_GAP_WALL_S:
            if sim_s > pts[-1][1]:  # the same instant: keep its freshest stamp
                pts[-1] = (pts[-1][0], sim_s)
                self._update()
            return
        pts.append((wall_s, sim_s))
        while wall_s - pts[0][0] > self.window_s:
            pts.popleft()
        self._update()

    def _update(self) -> None:
        pts = self._points
        span = pts[-1][0] - pts[0][0] if pts else 0.0
        if span < self.min_span_s or pts[-1][0] - self._updated_wall_s < UPDATE_EVERY_WALL_S:
            return  # keep the last rate (None at first): a fresh window has no say yet
        self._updated_wall_s = pts[-1][0]
        pts = list(pts)
        hull = upper_envelope(pts)
        t1, t3 = pts[0][0] + span / 4.0, pts[0][0] + 3.0 * span / 4.0
        rate = (envelope_at(hull, t3) - envelope_at(hull, t1)) / (t3 - t1)
        self._rate = rate if rate > 0 else self._rate
