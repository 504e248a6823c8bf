"""One mission's planners and schedule clocks, built in one place for every caller that flies it.

The headless runner (:func:`companion.planning.flight.headless.simulate`), the live companion
(``companion.app``: its flight context, and the warm-up before it) and anything else that flies a
mission call :func:`build_fleet`, so that what a vehicle's planner is made of (its route, the
routes above it for a detour, its timed route, where its sightline term acts) and how the timed
routes are read in flight (:class:`companion.planning.coordination.replan.ScheduleClocks`: the per-priority clocks of
:class:`companion.planning.coordination.clocks.PriorityClocks`, and the in-flight re-plan) cannot differ
between them:

    fleet = build_fleet(mission, routes, variant)
    # every tick, for every vehicle still flying, at that vehicle's own sample time:
    fleet.clocks.observe(name, (x, y), t)
    fleet.clocks.done(name)               # arrived (or no longer flying): holds nobody back
    for other, route in fleet.clocks.update(t).items():   # re-planned (seconds: a worker thread live)
        fleet.planners[other].adopt_timed(route, fleet.clocks.sight_near_m(other))
    tau = fleet.clocks.now(name, t)       # the time to read name's timed route at
    fleet.planners[name].tick(..., schedule_t_s=tau)

``clocks`` is None for the variants that fly no timed route.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from companion.planning.coordination.plan import CoordinatedPlan, plan_coordinated
from companion.planning.coordination.search import Blocking
from companion.planning.routes import higher_routes
from companion.planning.coordination.replan import ScheduleClocks
from companion.planning.coordination.clocks import sight_near_m
from companion.planning.flight.replay import FlownForecast, SoloFlight
from companion.planning.variants import VARIANTS
from companion.planning.vehicle_planner import VehiclePlanner
from uav_model.mission import CoordinationSettings

if TYPE_CHECKING:
    from collections.abc import Mapping

    from uav_model.mission import Mission
    from companion.planning.routes import Route
    from companion.planning.timed_route import TimedRoute


@dataclass(frozen=True, eq=False)
class FleetSetup:
    """Every vehicle's planner (by name, in priority order) and the clocks its timed route is read at."""

    planners: dict[str, VehiclePlanner]
    clocks: ScheduleClocks | None  # None: the variant flies no timed route
    timed: dict[str, TimedRoute]  # the timed routes flown (empty for the other variants)
    departure_hold_s: float | None = None  # the first vehicle's hold in the plan built here; None: none built
    coordination: CoordinationSettings = CoordinationSettings()  # the mission's, as the fleet was built under
    solo: SoloFlight | None = None  # the first vehicle's flight alone, to replay (flight.replay)


def build_fleet(mission: Mission, routes: Mapping[str, Route], variant: str | None = None,
                timed_routes: Mapping[str, TimedRoute] | None = None,
                blocking: Mapping[str, Blocking] | None = None, *, first: TimedRoute | None = None,
                plan: CoordinatedPlan | None = None) -> FleetSetup:
    """The planners and schedule clocks that fly ``mission`` with ``variant`` (default: the
    mission's). ``timed_routes`` (timed variants): the routes with arrival times to fly; by default
    the coordinated space-time plan (:func:`coordination.plan.plan_coordinated`, seconds of numpy)
    against ``first``, the first vehicle's forecast (:func:`forecast.first_forecast`), which the
    caller then passes in. A caller that already has the plan passes it in (``plan``), or only its
    routes, with their ``blocking``: what each plan keeps, which an in-flight re-plan must keep at
    least as well; unknown, any re-plan is adopted. From a plan, the first vehicle tracks what its
    forecast flight tracked, paced by its forecast (:attr:`CoordinatedPlan.first_tracks`); from
    routes alone, it tracks its own. A forecast flown headless (:class:`replay.FlownForecast`)
    brings its flight, for the runner to read the first vehicle back from (:attr:`FleetSetup.solo`)."""
    variant = variant or mission.planner.variant
    timed_variant = VARIANTS[variant].timed
    hold_s = None
    if plan is None and timed_routes is None and timed_variant and routes:
        if first is None:
            raise ValueError(f"build_fleet: variant {variant!r} plans against the first vehicle's forecast: "
                             f"pass first (forecast.first_forecast)")
        plan = plan_coordinated(mission, routes, first)  # the space-time plan (docs/design.md)
        hold_s = plan.hold_s
    if plan is not None:
        timed_routes, blocking = plan.timed, plan.blocking
    timed = dict(timed_routes or {})
    tracked, paced = (plan.tracked, plan.paced) if plan is not None else (timed.get, lambda name: None)
    planners = {v.name: VehiclePlanner.build(mission, v, routes.get(v.name), variant,
                                             earlier=higher_routes(mission, routes, v.name),
                                             timed_route=tracked(v.name), pace=paced(v.name),
                                             sight_near_m=sight_near_m(mission, timed, v.name))
                for v in mission.by_priority}
    return FleetSetup(planners, ScheduleClocks(mission, timed, blocking=blocking) if timed_variant else None, timed, hold_s,
                      mission.coordination, first.flight if isinstance(first, FlownForecast) else None)
