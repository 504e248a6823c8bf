"""The schedule clocks: the time at which each vehicle reads its timed route in flight, held back
while the vehicles above it lag their plans, and where a lower vehicle's sightline term acts."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from companion.planning.coordination.timed import closest_approach_m

if TYPE_CHECKING:
    from uav_model.mission import Mission
    from companion.planning.timed_route import TimedRoute


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
        self._window = (window_s, step_s, tolerance_m)  # what a reach found depends on, besides the route
        self._reach = {name: start_s for name in self.routes}  # start_s: a clock started mid-flight
        self._flying = dict(self._reach)  # the reaches of the vehicles not done: what holds the clock back
        self._done: set[str] = set()
        self._tau = start_s
        self.worst_lag_s = 0.0  # how far behind sim time the schedule fell, at most

    def observe(self, name: str, xy_enu_m, t_s: float, found: dict | None = None) -> None:
        """Vehicle ``name`` is at ``xy_enu_m`` at sim time ``t_s`` (since the common departure).
        ``found``: the reaches other clocks found for this observation, by (route, reach from,
        window): the clocks of the vehicles below one vehicle all follow it along the same route
        from the same reach (unless one was re-timed), so one of them works it out for all."""
        route = self.routes.get(name)
        if route is None:
            return
        key = (route, self._reach[name], self._window)
        latest = None if found is None else found.get(key)
        if latest is None:
            latest = route.latest_near_s(xy_enu_m, self._reach[name], self._offsets, self.tolerance_m)
            if found is not None:
                found[key] = latest
        self._reach[name] = reach = max(self._reach[name], latest)
        if name in self._flying:
            self._flying[name] = reach

    def done(self, name: str) -> None:
        """The vehicle has arrived: it no longer holds the clock back."""
        self._done.add(name)
        self._flying.pop(name, None)

    def lag_s(self, t_s: float) -> float:
        """How far the schedule is behind sim time now."""
        return t_s - self.now(t_s)

    def now(self, t_s: float) -> float:
        limit = min(self._flying.values(), default=np.inf) + self.slack_s
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
        self._watching: dict[str, list[ScheduleClock]] | None = None  # per vehicle, the clocks it holds back

    def retime(self, name: str, above: "dict[str, TimedRoute]", start_s: float) -> None:
        """``name`` was re-planned at ``start_s`` against ``above`` (the vehicles above it,
        re-forecast from where they were then): its clock is now theirs, from ``start_s`` on."""
        clock = ScheduleClock(above, **{**self._options, "start_s": start_s})
        for gone in self._done:
            clock.done(gone)
        self._clocks[name] = clock
        self._watching = None

    def observe(self, name: str, xy_enu_m, t_s: float) -> None:
        if self._watching is None:  # only the clocks that follow a vehicle are told where it is
            self._watching = {}
            for clock in self._clocks.values():
                for watched in clock.routes:
                    self._watching.setdefault(watched, []).append(clock)
        clocks = self._watching.get(name, ())
        if len(clocks) == 1:
            clocks[0].observe(name, xy_enu_m, t_s)
        elif clocks:
            found: dict = {}
            for clock in clocks:
                clock.observe(name, xy_enu_m, t_s, found)

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
    planned closest approach to the first vehicle (with assigned sight-line pairs: to the nearest
    of its partners) plus a margin (None: everywhere)."""
    partners = mission.hides_from(name)
    if partners is None:
        partners = (mission.by_priority[0].name,)
    partners = tuple(p for p in partners if p != name and p in timed_routes)
    if name not in timed_routes or not partners:
        return None
    return min(closest_approach_m(timed_routes[p], timed_routes[name]) for p in partners) + SIGHT_NEAR_MARGIN_M
