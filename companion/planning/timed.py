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

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from companion.planning.errors import PlanningError

if TYPE_CHECKING:
    from uav_model.mission import Mission

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
        for name, a in (("t_s", t), ("xy_enu_m", xy), ("_along_m", along)):
            a.setflags(write=False)
            object.__setattr__(self, name, a)

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
        last = np.flatnonzero(np.any(self.xy_enu_m != self.xy_enu_m[-1], axis=1))
        return float(self.t_s[last[-1] + 1]) if last.size else float(self.t_s[0])

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
        dt = np.diff(self.t_s)
        d = np.hypot(*np.diff(self.xy_enu_m, axis=0).T)
        return dt, np.where(dt > 0, d / np.where(dt > 0, dt, 1.0), 0.0)

    def _segment_index(self, t: np.ndarray) -> np.ndarray:
        """Index i of the segment [t_i, t_i+1] holding each t (clipped to the ends)."""
        if len(self.t_s) < 2:
            return np.zeros(t.shape, dtype=int)
        return np.clip(np.searchsorted(self.t_s, t, side="right") - 1, 0, len(self.t_s) - 2)

    def planned_position_at(self, t_s: np.ndarray | float) -> np.ndarray:
        """Planned positions (..., 2) at times ``t_s`` (...,)."""
        t = np.asarray(t_s, dtype=float)
        if len(self.t_s) == 1:
            return np.broadcast_to(self.xy_enu_m[0], t.shape + (2,)).copy()
        i = self._segment_index(t)
        t0, t1 = self.t_s[i], self.t_s[i + 1]
        span = t1 - t0
        u = np.clip(np.where(span > 0, (t - t0) / np.where(span > 0, span, 1.0), 1.0), 0.0, 1.0)
        p0, p1 = self.xy_enu_m[i], self.xy_enu_m[i + 1]
        return p0 + (p1 - p0) * u[..., None]

    def planned_speed_at(self, t_s: np.ndarray | float) -> np.ndarray:
        """Speed (...,) of the plan itself at ``t_s``: 0 while waiting and outside the route."""
        t = np.asarray(t_s, dtype=float)
        if len(self.t_s) == 1:
            return np.zeros(t.shape)
        _, v = self._segments()
        inside = (t >= self.t_s[0]) & (t < self.t_s[-1])
        return np.where(inside, v[self._segment_index(t)], 0.0)

    def is_waiting_at(self, t_s: np.ndarray | float) -> np.ndarray:
        """Whether the plan holds the vehicle still at ``t_s`` (before departure included, after
        arrival excluded: an arrived vehicle is done, not waiting)."""
        t = np.asarray(t_s, dtype=float)
        return (self.planned_speed_at(t) < _WAIT_SPEED_M_S) & (t < self.arrival_s)

    def planned_along_at(self, t_s: np.ndarray | float) -> np.ndarray:
        """How far along the route (m, ...) the plan is at ``t_s``."""
        return np.interp(np.asarray(t_s, dtype=float), self.t_s, self._along_m)

    def progress_at(self, xy_enu_m: np.ndarray, near_along_m: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(along, off) (...,) m: how far along the route the nearest route point to each of
        ``xy_enu_m`` (..., 2) is, and how far the position is from it. ``near_along_m``: where
        along the route the vehicle was last (see :func:`progress_window`): only the route within
        that window counts, so a path that passes near itself (out and back round a shadow, a wait
        beside a later leg) cannot throw the vehicle hundreds of metres ahead or behind."""
        xy = np.asarray(xy_enu_m, dtype=float)[..., None, :]
        if len(self.t_s) == 1:
            return np.zeros(xy.shape[:-2]), np.hypot(*np.moveaxis(xy[..., 0, :] - self.xy_enu_m[0], -1, 0))
        a, d = self.xy_enu_m[:-1], np.diff(self.xy_enu_m, axis=0)
        len2 = np.einsum("ij,ij->i", d, d)
        u = np.clip(np.einsum("...ij,ij->...i", xy - a, d) / np.where(len2 > 0, len2, 1.0), 0.0, 1.0)
        dist = np.hypot(*np.moveaxis(a + d * u[..., None] - xy, -1, 0))
        if near_along_m is not None:
            lo, hi = progress_window(near_along_m)
            inside = (self._along_m[1:] >= lo) & (self._along_m[:-1] <= hi)
            if inside.any():
                dist = np.where(inside, dist, np.inf)
        i = np.argmin(dist, axis=-1)[..., None]
        along = self._along_m[:-1] + u * np.sqrt(len2)
        return np.take_along_axis(along, i, -1)[..., 0], np.take_along_axis(dist, i, -1)[..., 0]

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
        gap = self.planned_along_at(np.asarray(t_s, dtype=float) + lookahead_s) - along
        return np.where(gap > 0, np.minimum(np.hypot(gap, off) / lookahead_s, max_speed_m_s), 0.0)


PROGRESS_BACK_M, PROGRESS_AHEAD_M = 30.0, 60.0  # a vehicle flies ~5 m a tick; see progress_window


def progress_window(near_along_m: float) -> tuple[float, float]:
    """The stretch of a route (m along it) a vehicle last seen ``near_along_m`` along can be on
    a tick later: a little behind (it drifts back while it waits, or turns), more ahead."""
    return near_along_m - PROGRESS_BACK_M, near_along_m + PROGRESS_AHEAD_M


def closest_approach_m(first: TimedRoute, second: TimedRoute, step_s: float = 0.5) -> float:
    """The least planned distance between two timed routes (sampled every ``step_s``)."""
    end = max(first.t_s[-1], second.t_s[-1])
    t = np.arange(min(first.t_s[0], second.t_s[0]), end + step_s, step_s)
    return float(np.hypot(*(first.planned_position_at(t) - second.planned_position_at(t)).T).min())


def forecast(vehicle: str, route_enu_m: np.ndarray, speed_m_s: float, hold_s: float = 0.0,
             start_s: float = 0.0) -> TimedRoute:
    """A vehicle flying ``route_enu_m`` (M, 2) at constant ``speed_m_s`` after holding ``hold_s``
    at its first point (the forecast of a higher-priority vehicle)."""
    if not speed_m_s > 0:
        raise PlanningError(f"forecast of {vehicle!r}: speed must be positive, got {speed_m_s!r}")
    if not hold_s >= 0:
        raise PlanningError(f"forecast of {vehicle!r}: hold must be >= 0 s, got {hold_s!r}")
    p = np.asarray(route_enu_m, dtype=float).reshape(-1, 2)
    t = start_s + np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(p, axis=0).T))]) / speed_m_s
    return held(TimedRoute(vehicle, t, p), hold_s)


def held(route: TimedRoute, hold_s: float) -> TimedRoute:
    """``route`` delayed by a departure hold of ``hold_s`` at its first point: it still starts
    when it did, and waits there that long before going on as before."""
    if not hold_s > 0:
        return route
    return TimedRoute(route.vehicle, np.concatenate([route.t_s[:1], route.t_s + hold_s]),
                      np.vstack([route.xy_enu_m[:1], route.xy_enu_m]))


def _nearest_on(p: np.ndarray, here: np.ndarray) -> tuple[int, float, np.ndarray]:
    """The point of the polyline ``p`` (M >= 2, 2) nearest ``here``: its segment, the fraction
    along it, and the point (the first segment on ties)."""
    a, d = p[:-1], np.diff(p, axis=0)
    len2 = np.einsum("ij,ij->i", d, d)
    u = np.clip(np.einsum("ij,ij->i", here - a, d) / np.where(len2 > 0, len2, 1.0), 0.0, 1.0)
    foot = a + d * u[:, None]
    i = int(np.argmin(np.hypot(*(foot - here).T)))
    return i, float(u[i]), foot[i]


def forecast_from(vehicle: str, route_enu_m: np.ndarray, xy_enu_m: tuple[float, float], t_s: float,
                  speed_m_s: float) -> TimedRoute:
    """A vehicle seen at ``xy_enu_m`` at time ``t_s`` flying the rest of ``route_enu_m`` at
    ``speed_m_s``: from its nearest point on the route (a re-forecast of a higher-priority vehicle
    that strayed from its plan)."""
    p = np.asarray(route_enu_m, dtype=float).reshape(-1, 2)
    here = np.asarray(xy_enu_m, dtype=float)
    if len(p) < 2:
        return forecast(vehicle, np.vstack([here, p]), speed_m_s, start_s=t_s)
    i, _, foot = _nearest_on(p, here)
    rest = np.vstack([here, foot, p[i + 1:]])
    return forecast(vehicle, rest, speed_m_s, start_s=t_s)


def forecast_along(route: TimedRoute, xy_enu_m: tuple[float, float], t_s: float, speed_m_s: float) -> TimedRoute:
    """A vehicle seen at ``xy_enu_m`` at time ``t_s`` going on as its timed ``route`` has it fly:
    to the route's nearest point at ``speed_m_s``, then the rest at the route's own pace, shifted
    to begin when it gets there. For a flown forecast (:mod:`flown_forecast`) that keeps its
    slower corners and final approach, which :func:`forecast_from` would fly at cruise. Waits
    are left out (only their last instant is kept): a vehicle seen once it left does not wait
    again."""
    keep = np.ones(len(route.t_s), dtype=bool)
    keep[:-1] = np.any(route.xy_enu_m[1:] != route.xy_enu_m[:-1], axis=1)
    p, t = route.xy_enu_m[keep], route.t_s[keep]
    here = np.asarray(xy_enu_m, dtype=float)
    if len(p) < 2:
        return forecast(route.vehicle, np.vstack([here, p]), speed_m_s, start_s=t_s)
    i, u, foot = _nearest_on(p, here)
    at_foot = t_s + float(np.hypot(*(foot - here))) / speed_m_s
    shift = at_foot - (t[i] + u * (t[i + 1] - t[i]))
    return TimedRoute(route.vehicle, np.concatenate([[t_s, at_foot], t[i + 1:] + shift]),
                      np.vstack([here, foot, p[i + 1:]]))


class ScheduleClock:
    """The schedule's time for a fleet flying timed routes together: time since the common
    departure, held back while a vehicle lags its plan, so that the others wait for it.

    The plans keep the vehicles apart and their sight lines blocked at every planned instant
    (static obstacles only). Re-timing every plan by one common, monotone clock keeps every
    vehicle where the plan had it relative to the others; a vehicle that lost time (a telemetry
    gap it hovered through, ticks the companion could not keep up with) would otherwise arrive
    late at the place the plan timed against the others. Each vehicle's *reach* is the latest
    plan time its position is consistent with (the end of a wait it sits in, its closest planned
    point along the route); the clock runs at most ``slack_s`` ahead of the least reach of the
    vehicles still flying, and never more than ``max_lag_s`` behind sim time (a vehicle that far
    off its plan has left it: waiting for it would stop everybody).

        clock = ScheduleClock(plan.timed)
        clock.observe("b", (x, y), t)   # each tick, before asking the time
        tau = clock.now(t)              # the time to track the plans at
    """

    def __init__(self, routes: "dict[str, TimedRoute]", *, slack_s: float = 2.0, max_lag_s: float = 120.0,
                 window_s: float = 60.0, step_s: float = 0.5, tolerance_m: float = 1.0, start_s: float = 0.0):
        self.routes = dict(routes)
        self.slack_s, self.max_lag_s, self.tolerance_m = slack_s, max_lag_s, tolerance_m
        self._offsets = np.arange(0.0, window_s + step_s / 2, step_s)
        self._reach = {name: start_s for name in self.routes}  # start_s: a clock started mid-flight
        self._done: set[str] = set()
        self._tau = start_s
        self.worst_lag_s = 0.0  # how far behind sim time the schedule fell, at most

    def observe(self, name: str, xy_enu_m, t_s: float) -> None:
        """Vehicle ``name`` is at ``xy_enu_m`` at sim time ``t_s`` (since the common departure)."""
        route = self.routes.get(name)
        if route is None:
            return
        times = self._reach[name] + self._offsets
        d = np.hypot(*(route.planned_position_at(times) - np.asarray(xy_enu_m, dtype=float)).T)
        latest = times[np.flatnonzero(d <= d.min() + self.tolerance_m)[-1]]
        self._reach[name] = max(self._reach[name], float(latest))

    def done(self, name: str) -> None:
        """The vehicle has arrived: it no longer holds the clock back."""
        self._done.add(name)

    def lag_s(self, t_s: float) -> float:
        """How far the schedule is behind sim time now."""
        return t_s - self.now(t_s)

    def now(self, t_s: float) -> float:
        flying = [r for n, r in self._reach.items() if n not in self._done]
        limit = min(flying, default=np.inf) + self.slack_s
        self._tau = max(self._tau, min(t_s, max(limit, t_s - self.max_lag_s)))
        self.worst_lag_s = max(self.worst_lag_s, t_s - self._tau)
        return self._tau


class PriorityClocks:
    """Each vehicle's schedule time when the vehicles above it are not where their plans have
    them: sim time for the first in priority (it waits for nobody, the paper's rule); for every
    other, a :class:`ScheduleClock` over the vehicles above it only. A lower vehicle's plan keeps
    its sight line blocked against the *forecasts* of the higher ones; on the multicopter the
    first lags its forecast by ~10-150 m (slower turns), and tracking the plan by sim time put
    the lower one at the planned place with the higher one elsewhere. Read at the clock, the
    lower vehicle keeps its planned place relative to where the higher ones really are.

        clocks = PriorityClocks(plan.timed, ["a", "b"])
        clocks.observe("a", (x, y), t)   # every flying vehicle, each tick
        clocks.done("a")                 # arrived
        tau = clocks.now("b", t)         # the time to track b's timed route at
    """

    def __init__(self, routes: "dict[str, TimedRoute]", order: "list[str]", **clock_options: float):
        self._options = clock_options
        self._clocks = {name: ScheduleClock({m: routes[m] for m in order[:i] if m in routes}, **clock_options)
                        for i, name in enumerate(order) if i > 0 and name in routes}
        self._done: set[str] = set()

    def retime(self, name: str, above: "dict[str, TimedRoute]", start_s: float) -> None:
        """``name`` was re-planned at ``start_s`` against ``above`` (the vehicles above it,
        re-forecast from where they were then): its clock is now theirs, from ``start_s`` on."""
        clock = ScheduleClock(above, **{**self._options, "start_s": start_s})
        for gone in self._done:
            clock.done(gone)
        self._clocks[name] = clock

    def observe(self, name: str, xy_enu_m, t_s: float) -> None:
        for clock in self._clocks.values():
            clock.observe(name, xy_enu_m, t_s)

    def done(self, name: str) -> None:
        self._done.add(name)
        for clock in self._clocks.values():
            clock.done(name)

    def now(self, name: str, t_s: float) -> float:
        clock = self._clocks.get(name)
        return t_s if clock is None else clock.now(t_s)


class KeptHold:
    """The first vehicle's departure hold, kept against the vehicles below it when no
    :class:`PriorityClocks` run (live, one clock per vehicle: independent autopilots). The plan times the
    hold so that the lower vehicles, on their timed routes from t = 0, meet the first where their
    sight lines stay blocked; a lower vehicle that falls behind its plan meanwhile (a real
    multicopter gets to cruise from a hover more slowly than planned) meets it late, with the line
    open. While it holds, the first reads its route at a :class:`ScheduleClock` over the lower
    vehicles, so it departs as much later as they lag, by at most ``extra_max_s`` (what the
    mission's ``hold_s_max`` leaves); from its departure on it reads sim time less the extra hold
    it took: in flight it waits for nobody.

        kept = KeptHold(timed["a"], {"b": timed["b"]}, extra_max_s=hold_s_max - hold_s)
        kept.observe("b", (x, y), t)   # the lower vehicles, while the first holds
        tau = kept.now(t)              # the time to read the first's timed route at
    """

    def __init__(self, first: TimedRoute, below: "dict[str, TimedRoute]", extra_max_s: float):
        self.departure_s = first.departure_s
        self._clock = ScheduleClock(below, slack_s=0.0) if below and first.departure_s > 0 else None
        self.extra_max_s = max(0.0, extra_max_s)
        self.extra_s: float | None = None  # the extra hold taken, fixed at the departure

    def observe(self, name: str, xy_enu_m, t_s: float) -> None:
        if self._clock is not None and self.extra_s is None:
            self._clock.observe(name, xy_enu_m, t_s)

    def done(self, name: str) -> None:
        if self._clock is not None:
            self._clock.done(name)

    def now(self, t_s: float) -> float:
        if self.extra_s is not None:
            return t_s - self.extra_s
        tau = t_s if self._clock is None else max(self._clock.now(t_s), t_s - self.extra_max_s)
        if tau >= self.departure_s:
            self.extra_s = t_s - tau
        return tau


SIGHT_NEAR_MARGIN_M = 200.0  # see VehiclePlanner.sight_near_m; chosen on a tuning seed


def sight_near_m(mission: "Mission", timed_routes: dict[str, TimedRoute], name: str) -> float | None:
    """Where a lower vehicle's sightline term acts when it tracks a timed route: within the
    planned closest approach to the first vehicle plus a margin (None: everywhere)."""
    first = mission.by_priority[0].name
    if name == first or name not in timed_routes or first not in timed_routes:
        return None
    return closest_approach_m(timed_routes[first], timed_routes[name]) + SIGHT_NEAR_MARGIN_M
