"""In-flight re-planning of the timed routes: :class:`ScheduleClocks`, the per-tick object a runner
(headless or live) asks for each vehicle's schedule time, and which re-plans a lower-priority
vehicle that has fallen behind its space-time plan.

Before flight every lower vehicle is planned against the *forecasts* of the vehicles above it
(:mod:`coordination`); :class:`timed.PriorityClocks` then reads its plan at a clock held back
while those vehicles lag their forecasts. What the clock cannot absorb is the lower vehicle's own
lag: a vehicle 100-600 m behind its plan (the sightline term made it hide and hover, a long turn,
a detour round a moving obstacle) is not where its plan keeps the sight line blocked, and the
plan's times ask for cruise until the end, so it never gets back.
Then, before the plan's closest approach, :meth:`ScheduleClocks.update` plans it again in (position,
time) from where it is, at the time it is, against the vehicles above it re-forecast from where
they are (:func:`coordination.plan_vehicle` with ``from_xy`` / ``t0_s``), then each flying vehicle
below it that either lags its own plan too or has a vehicle above it with a new plan from this
re-plan (the others' plans were made against what still stands: they keep them). A new plan is
adopted only when it keeps the sight line at least as well as the old one did (a re-plan that
can only keep separation would give up what the old plan might still catch), and its clock
restarts at the re-plan's time.

    fleet = ScheduleClocks(mission, plan.timed)
    fleet.observe("a", (x, y), t); fleet.observe("b", (x, y), t)   # every flying vehicle
    for name, route in fleet.update(t).items():                    # re-planned this tick
        planners[name].adopt_timed(route, fleet.sight_near_m(name))
    tau = fleet.now("b", t)                                        # the time to track b's route at

Pure: no I/O and no clocks of its own. A re-plan costs what a pre-flight plan of one vehicle
costs (about 0.3-2 s at 10 m cells), so a live caller takes :meth:`update`'s three steps apart and
runs only the middle one in a worker thread, one re-plan at a time (``companion.app.context``):

    job = fleet.job(t)                        # on the loop, cheap: None, or the inputs copied
    planned = await asyncio.to_thread(fleet.plan, job)   # seconds; reads the job, not the fleet
    for name, route in fleet.adopt(job, planned).items():  # on the loop: routes, clocks, counters
        planners[name].adopt_timed(route, fleet.sight_near_m(name))

:meth:`observe`, :meth:`done` and :meth:`now` may run meanwhile: :meth:`plan` touches none of
their state.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from uav_model.mission import Forecast
from companion.planning.coordination.search import Blocking, plan_vehicle
from companion.planning.grid import rasterise
from companion.planning.coordination.shadow import SightShadows
from companion.planning.coordination.clocks import PriorityClocks, sight_near_m
from companion.planning.coordination.timed import forecast_along, forecast_from
from companion.planning.timed_route import TimedRoute

if TYPE_CHECKING:
    from uav_model.mission import Mission

_STRICTNESS = {Blocking.NONE: 0, Blocking.CLOSEST_APPROACH: 1, Blocking.WHOLE_FLIGHT: 2}


@dataclass(frozen=True)
class ReplanRule:
    """When a lower vehicle is re-planned in flight: it lags its plan by more than ``lag_m``
    along its path, before the plan's closest approach to a vehicle above it, at most every
    ``every_s`` and ``most`` times per flight. The numbers are set by judgement, not tuned; the
    "before the closest approach" condition was chosen on a tuning seed: without it, re-plans
    after the closest approach make b slower and block nothing more."""

    lag_m: float = 100.0
    every_s: float = 30.0
    most: int = 6


@dataclass(frozen=True)
class ReplanJob:
    """One re-plan's inputs, copied when it was found due (:meth:`ScheduleClocks.job`): the vehicles
    to plan (the one due first, then every flying one below it, each planned only as
    :meth:`ScheduleClocks.plan` says), where each was, and where every
    vehicle above the last of them will be, all at ``t_s``."""

    t_s: float
    names: tuple[str, ...]
    xy: "dict[str, tuple[float, float]]"
    forecasts: "dict[str, TimedRoute]"
    blocking: "dict[str, Blocking]"  # what each plan kept when the job was made
    lagging: frozenset[str] = frozenset()  # those below the first that lag their own plans (:meth:`ScheduleClocks.lags`)


@dataclass(frozen=True)
class Replanned:
    """One vehicle's new plan (:meth:`ScheduleClocks.plan`), not yet adopted: what it keeps, and the
    forecasts above it that it was made against."""

    name: str
    route: TimedRoute
    level: Blocking
    above: "dict[str, TimedRoute]"


def closest_approach_s(first: TimedRoute, second: TimedRoute, step_s: float = 0.5) -> float:
    """When two timed routes are planned closest (sampled every ``step_s``; the earliest on ties)."""
    t = np.arange(min(first.t_s[0], second.t_s[0]), max(first.t_s[-1], second.t_s[-1]) + step_s, step_s)
    return float(t[np.argmin(np.hypot(*(first.planned_position_at(t) - second.planned_position_at(t)).T))])


class ScheduleClocks:
    """:class:`PriorityClocks` (``observe`` / ``done`` / ``now``, the same calls) that also
    re-plans a lower vehicle gone astray of its plan (:meth:`update`; see the module doc)."""

    def __init__(self, mission: "Mission", routes: "dict[str, TimedRoute]", rule: ReplanRule = ReplanRule(), *,
                 grid=None, shadows: SightShadows | None = None, blocking: "dict[str, Blocking] | None" = None):
        self.mission = mission
        self.coordination = mission.coordination  # read once: re-plans on or off, the first's forecast
        self.rule = rule
        self.order = [v.name for v in mission.by_priority if v.name in routes]
        self.routes = dict(routes)
        self.clocks = PriorityClocks(self.routes, self.order)
        self._grid, self._shadows, self._memo = grid, shadows, {}
        # What each plan keeps; unknown (a caller's own routes): any re-plan is adopted.
        self.blocking = dict(blocking or {})
        self._xy: dict[str, object] = {}  # each vehicle's newest (x, y), as given
        self._along: dict[str, float] = {}  # first seen: anywhere on its path; then near where it was
        self._seen_s: dict[str, float] = {}  # the time of each vehicle's newest position
        self._done: set[str] = set()
        self._past_ca: set[str] = set()  # read past the planned closest approach: no re-plan until a new plan
        self._last: dict[str, float] = {}
        self._above: dict[str, dict[str, TimedRoute]] = {}  # what a re-plan was made against
        self.replans = {name: 0 for name in self.order}  # adopted re-plans per vehicle
        self.tries = {name: 0 for name in self.order}  # re-plans made (adopted or not)
        self._ca_s = {name: self._closest_s(name) for name in self.order[1:]}
        self._straying = {name for name in self.order if self._may_stray(name)}  # see _may_stray

    # -- the PriorityClocks calls ------------------------------------------------------------
    def observe(self, name: str, xy_enu_m, t_s: float) -> None:
        self._xy[name] = xy_enu_m  # read as floats only by a re-plan
        self._seen_s[name] = t_s
        if name in self._straying:  # where it is along its path, windowed as the planner's own
            self._along[name] = float(self.routes[name].progress_of(float(xy_enu_m[0]), float(xy_enu_m[1]),
                                                                    self._along.get(name))[0])
        self.clocks.observe(name, xy_enu_m, t_s)

    def done(self, name: str) -> None:
        self._done.add(name)
        self._straying.discard(name)
        self.clocks.done(name)

    def now(self, name: str, t_s: float) -> float:
        return self.clocks.now(name, t_s)

    def sight_near_m(self, name: str) -> float | None:
        """Where ``name``'s sightline term acts on its current plan (:func:`timed.sight_near_m`)."""
        return sight_near_m(self.mission, self._against(name), name)

    def _against(self, name: str) -> "dict[str, TimedRoute]":
        """The routes ``name``'s plan was made against, and its own."""
        return {**self.routes, **self._above.get(name, {}), name: self.routes[name]}

    # -- re-planning -------------------------------------------------------------------------
    def _may_stray(self, name: str) -> bool:
        """Whether :meth:`strayed` can still hold for ``name`` on its current plan: never for the
        first in priority, a vehicle done, re-plans off or used up, or a plan read past its closest
        approach (the schedule clock never runs back; a new plan starts its progress afresh). Only
        then is its progress along the plan followed, every tick (``_straying``: re-read by
        :meth:`_follow` whenever one of these changes)."""
        return (name in self._ca_s and name not in self._done and name not in self._past_ca
                and self.coordination.replan and self.tries[name] < self.rule.most)

    def _follow(self, name: str) -> None:
        if self._may_stray(name):
            self._straying.add(name)
        else:
            self._straying.discard(name)

    def strayed(self, name: str, t_s: float) -> bool:
        """Whether lower vehicle ``name`` (observed this tick) is due for a re-plan at ``t_s``.
        Not before it has been observed on its current plan: a plan just adopted has no progress
        along it yet (live, adopted between two of its samples, after a re-plan that took longer
        than ``every_s`` of sim time). Never when the mission turns re-plans off
        (``coordination.replan: false``)."""
        if not self.coordination.replan or name not in self._ca_s or name in self._done \
                or name not in self._along:
            return False
        if self.tries[name] >= self.rule.most or t_s - self._last.get(name, -np.inf) < self.rule.every_s:
            return False
        tau = self.now(name, t_s)
        if tau >= self._ca_s[name]:
            self._past_ca.add(name)
            self._straying.discard(name)
            return False  # past the planned closest approach: re-plans from there cost more than they save
        return self._behind(name, tau)

    def lags(self, name: str, t_s: float) -> bool:
        """Whether ``name`` (observed on its current plan) is more than ``lag_m`` behind it,
        before the plan's closest approach: what :meth:`strayed` asks, without its gates on
        when and how often."""
        if name not in self._along or name not in self._ca_s:
            return False
        tau = self.now(name, t_s)
        return tau < self._ca_s[name] and self._behind(name, tau)

    def _behind(self, name: str, tau: float) -> bool:
        """Whether ``name`` is more than ``lag_m`` behind where its plan is at schedule time ``tau``."""
        return float(self.routes[name].planned_along_at(tau)) - self._along[name] > self.rule.lag_m

    def fresh(self, t_s: float) -> bool:
        """Whether every flying vehicle's newest position is at most the mission's
        ``safety.telemetry_timeout_s`` older than ``t_s``. Live, a vehicle's position stream can
        stop while the others fly on: a re-plan would start it where it was seen last, at a time
        it is no longer there (or forecast a vehicle above it from there). Headless every vehicle
        is observed every tick: always fresh."""
        limit = self.mission.safety.telemetry_timeout_s
        seen = self._seen_s
        if not seen or t_s - min(seen.values()) <= limit:  # every vehicle fresh (headless: every tick)
            return True
        return all(t_s - seen <= limit for name, seen in self._seen_s.items() if name not in self._done)

    def update(self, t_s: float) -> "dict[str, TimedRoute]":
        """Re-plan the first lower vehicle due (:meth:`strayed`) and the flying ones below it
        that need it (:meth:`plan`);
        the new routes adopted, by name (empty: nothing changed). The three steps at once, as
        the headless runner takes them; a live caller takes them apart (module doc)."""
        job = self.job(t_s)
        return {} if job is None else self.adopt(job, self.plan(job))

    def job(self, t_s: float) -> ReplanJob | None:
        """Step 1 (cheap, the caller's side): the re-plan due at ``t_s``, its inputs copied (None:
        nothing due). Counts it as tried: ``every_s`` and ``most`` hold from now, adopted or not.
        None, uncounted, while a flying vehicle's newest position is stale (:meth:`fresh`)."""
        if not self.fresh(t_s):
            return None
        for due in self.order[1:]:
            if due in self._along and self.strayed(due, t_s):  # no progress known: not due (strayed)
                break
        else:
            return None
        names = tuple(n for n in self.order[self.order.index(due):] if n not in self._done and n in self._xy)
        for name in names:
            self._last[name] = t_s
            self.tries[name] += 1
            self._follow(name)
        above = self.order[:self.order.index(names[-1])]
        return ReplanJob(t_s, names, {n: (float(self._xy[n][0]), float(self._xy[n][1])) for n in names},
                         {o: self._forecast(o, t_s) for o in above}, dict(self.blocking),
                         frozenset(n for n in names[1:] if self.lags(n, t_s)))

    def plan(self, job: ReplanJob) -> "list[Replanned]":
        """Step 2 (seconds of CPU; a worker thread live): plan ``job``'s vehicles in priority order,
        each against the forecasts above it and the new plans above it in this job; one below the
        first only when a vehicle above it has a new plan by then or it lags its own
        (``job.lagging``): otherwise its plan was made against what still stands. Reads only
        ``job`` and the immutable mission; writes only the planning caches (grid, shadows, memo),
        which nothing else touches: safe beside :meth:`observe` / :meth:`now`, one job at a time."""
        if self._grid is None:
            self._grid = rasterise(self.mission.world, self.mission.planner.grid_resolution_m)
        if self._shadows is None:
            self._shadows = SightShadows(self.mission.world, self._grid)
        forecasts = dict(job.forecasts)
        out: list[Replanned] = []
        for name in job.names:
            if name != job.names[0] and not out and name not in job.lagging:
                continue  # nothing above it has a new plan and it keeps to its own: its plan stands
            above = {o: forecasts[o] for o in self.order[:self.order.index(name)]}
            found = plan_vehicle(self.mission, name, tuple(above.values()), self._grid, self._shadows, self._memo,
                                 from_xy=job.xy[name], t0_s=job.t_s)
            if found is None:
                continue
            route, level, _ = found
            old = job.blocking.get(name)
            if old is not None and _STRICTNESS[level] < _STRICTNESS[old]:
                continue  # keeps the sight line less well than the old plan meant to
            out.append(Replanned(name, route, level, above))
            # As a forecast for those below: its clock, restarted at t_s (adopt), reads t_s: no shift.
            forecasts[name] = route
        return out

    def adopt(self, job: ReplanJob, planned: "list[Replanned]") -> "dict[str, TimedRoute]":
        """Step 3 (cheap, the caller's side): install ``planned`` (clocks restarted at the job's
        time); a vehicle done meanwhile keeps what it had. The routes adopted, by name."""
        adopted: dict[str, TimedRoute] = {}
        for new in planned:
            name = new.name
            if name in self._done:
                continue
            self.routes[name], self.blocking[name] = new.route, new.level
            self._along.pop(name, None)
            self._past_ca.discard(name)
            self._above[name] = new.above
            self.clocks.retime(name, new.above, job.t_s)
            self._ca_s[name] = self._closest_s(name)
            self._follow(name)
            self.replans[name] += 1
            adopted[name] = new.route
        return adopted

    def _forecast(self, other: str, t_s: float) -> TimedRoute:
        """Where vehicle ``other`` will be from ``t_s``, for those below it: the first (it waits
        for nobody) along the rest of its route from where it is, as it was forecast (the flown
        forecast at its own pace, the route at cruise); every other on its own plan, shifted by
        how far its clock is behind sim time; an arrived one parked."""
        route = self.routes[other]
        if other in self._done or other not in self._xy:
            return TimedRoute(other, np.array([t_s]), route.xy_enu_m[-1:])
        if other == self.order[0] and t_s < route.departure_s:
            return route  # still holding: it departs on its schedule (sim time)
        if other == self.order[0]:
            v = self.mission.vehicle(other)
            xy = tuple(np.asarray(self._xy[other], dtype=float))
            if self.coordination.forecast is Forecast.FLOWN:
                return forecast_along(route, xy, t_s, v.speed_m_s)
            return forecast_from(other, route.path_xy, xy, t_s, v.speed_m_s)
        return TimedRoute(other, route.t_s + (t_s - self.now(other, t_s)), route.xy_enu_m)

    def _closest_s(self, name: str) -> float:
        """The latest planned closest approach of ``name`` to a vehicle above it (that it hides
        from, when it is assigned partners)."""
        routes = self._against(name)
        above = self.order[:self.order.index(name)]
        above = [o for o in above if o in (self.mission.hides_from(name) or ())] or above
        return max(closest_approach_s(routes[o], routes[name]) for o in above)
