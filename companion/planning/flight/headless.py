"""Headless in-process runner: a mission flown by its planners on the shared plant, and scored.

    result = simulate(mission, "astar-bdwa-timed")
    result.summary, result.tracks["a"], result.speed_factor

No sockets and no clocks: the fleet the live companion builds (:func:`fleet_setup.build_fleet`),
flown by the tick loop of :mod:`loop`. A timed variant flies the coordinated space-time plan,
made against the first vehicle's forecast (:func:`forecast.first_forecast`): a caller that has
that forecast already (the occlusion certificate judges the same one) passes it in, so that the
first vehicle is not flown alone a second time.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

from companion.planning.flight.fleet_setup import build_fleet
from companion.planning.flight.forecast import first_forecast, mission_certificates
from companion.planning.flight.loop import RunResult, fly
from companion.planning.routes import plan_routes
from companion.planning.variants import VARIANTS, variant_needs_route

if TYPE_CHECKING:
    from uav_model.mission import Mission
    from companion.planning.budget import Budget
    from companion.planning.coordination.certificate import OcclusionCertificate
    from companion.planning.routes import Route
    from companion.planning.timed_route import TimedRoute


def simulate(mission: Mission, variant: str | None = None, *,
             routes: dict[str, Route] | None = None,
             lower_bounds_s: dict[str, float | None] | None = None,
             timed_routes: dict[str, TimedRoute] | None = None,
             first: TimedRoute | None = None,
             budget: Budget | None = None) -> RunResult:
    """Fly ``mission`` headless with ``variant`` (default: the mission's) and score it.
    ``timed_routes``: routes with arrival times per vehicle, tracked by the timed variant; by
    default it flies the coordinated space-time plan (:func:`coordination.plan.plan_coordinated`)
    against ``first``, the first vehicle's forecast (default: :func:`forecast.first_forecast`
    of this mission and variant).

    ``routes`` and ``lower_bounds_s`` (see :func:`metrics.vehicle_lower_bound_s`) do not depend
    on the variant: a caller flying several variants of one mission may pass them in once.

    Raises :class:`companion.planning.errors.NoPath` when an A* variant finds no route, and
    :class:`companion.planning.budget.BudgetSpent` when ``budget`` (a unit per tick) runs out.
    """
    started = time.perf_counter()
    if variant is not None:
        mission = mission.with_variant(variant)
    variant = mission.planner.variant
    if routes is None:
        routes = plan_routes(mission) if variant_needs_route(variant) else {}
    if first is None and timed_routes is None and routes and VARIANTS[variant].timed:
        first = first_forecast(mission, routes)
    fleet = build_fleet(mission, routes, variant, timed_routes, first=first)  # the live companion builds the same
    return fly(mission, fleet, routes, lower_bounds_s=lower_bounds_s, budget=budget, started=started)


def flight_inputs(mission: Mission) -> tuple[dict[str, Route], TimedRoute | None]:
    """What flying ``mission`` (its variant set) and certifying it both need, computed once: its
    routes (none for the station-goal variants) and the first vehicle's forecast (None with one
    vehicle, or when the first has no route). Pass them to :func:`simulate_certified` (and to a
    warm-up flight before it), so that the first vehicle is flown alone once."""
    routes = plan_routes(mission) if variant_needs_route(mission.planner.variant) else {}
    first = None
    if len(mission.vehicles) > 1 and mission.by_priority[0].name in routes:
        first = first_forecast(mission, routes)
    return routes, first


def simulate_certified(mission: Mission, variant: str | None = None, *,
                       inputs: tuple[dict[str, Route], TimedRoute | None] | None = None,
                       ) -> tuple[RunResult, tuple[OcclusionCertificate, ...]]:
    """:func:`simulate`, and the occlusion certificate of each scored pair, of the forecasts that
    ``variant`` flies (:func:`forecast.mission_certificates`, the headline first): the first
    vehicle is flown alone once, for both.
    ``inputs``: :func:`flight_inputs` of this mission and variant, when the caller has them."""
    if variant is not None:
        mission = mission.with_variant(variant)
    routes, first = flight_inputs(mission) if inputs is None else inputs
    run = simulate(mission, routes=routes, first=first)
    return run, mission_certificates(mission, routes, first=first)
