"""The first vehicle's forecast as it will fly: its own planner on the mission's plant, alone.

    first = first_forecast(mission, routes)               # flown once per mission and variant
    plan = plan_coordinated(mission, routes, first)       # what the lower vehicles plan against
    certificate = mission_certificate(mission, routes, first=first)   # and what the certificate judges

The lower vehicles are planned in (position, time) against a forecast of the first
(:mod:`coordination`). A forecast along its sparse route at cruise can be 80-110 m off where the
multicopter really flies (it rounds the route's corners and keeps its distance from the
obstacles), so b, planned to hide behind an obstacle from that forecast, meets the real one
elsewhere with the line open. Flown alone headless first, with the runner that flies the
mission (:mod:`loop`), the forecast is 5-25 m off. The lower vehicles change the
first one's flight only through the separation rule, which binds only when they meet.

The default (``coordination.forecast: flown``). Pure and deterministic: no I/O. It costs one headless
flight of one vehicle.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

from uav_model.mission import Forecast
from companion.planning.budget import BudgetSpent
from companion.planning.coordination.certificate import OcclusionCertificate, certify
from companion.planning.coordination.plan import route_forecast
from companion.planning.errors import NoPath
from companion.planning.flight.fleet_setup import build_fleet
from companion.planning.flight.loop import fly
from companion.planning.flight.replay import FlownForecast
from companion.planning.routes import plan_routes
from companion.planning.timed_route import TimedRoute

if TYPE_CHECKING:
    from collections.abc import Mapping

    from companion.planning.budget import Budget
    from uav_model.mission import Mission
    from companion.planning.routes import Route

_EVERY = 2  # keep every second sample of the track (1 s at the runner's 0.5 s step)


def flown_forecast(mission: "Mission", route: "Route", name: str, budget: "Budget | None" = None) -> TimedRoute:
    """Where ``name`` flies, and when, flying ``route`` alone from t = 0: its headless track,
    then straight on to its goal at cruise if it stopped short (it arrives within the arrival
    radius, or the time limit ended the flight). A departure hold delays it as a whole
    (:func:`timed.held`): the moving obstacles it meets then are elsewhere, which the flight
    itself absorbs as it absorbs any other difference from its forecast. ``budget``: charged a
    unit per tick (:mod:`budget`)."""
    vehicle = mission.vehicle(name)
    alone = dataclasses.replace(mission, vehicles=(vehicle,), assigned_pairs=None)  # alone, it hides from nobody
    routes = {name: route}
    # Alone, it is planned against nobody: a timed variant tracks its route at cruise.
    fleet = build_fleet(alone, routes, first=route_forecast(alone, routes))
    # Alone, nobody holds its schedule back: it reads its route at sim time, without the clocks' bookkeeping.
    fleet = dataclasses.replace(fleet, clocks=None)
    # Only the track is wanted: no lower bound to score it against (on a large mission that
    # bound's visibility graph costs more than the flight, and no budget meters it).
    flown = fly(alone, fleet, routes, lower_bounds_s={name: None}, budget=budget, record=name)
    track = flown.tracks[name]
    t, xy = np.asarray(track.t_s, dtype=float), np.column_stack([track.x_m, track.y_m])
    keep = np.zeros(len(t), dtype=bool)
    keep[::_EVERY] = True
    keep[-1] = True
    t, xy = t[keep], xy[keep]
    goal = np.asarray(vehicle.goal_enu_m, dtype=float)
    t = np.append(t, t[-1] + float(np.hypot(*(goal - xy[-1]))) / vehicle.speed_m_s)
    return FlownForecast(name, t, np.vstack([xy, goal]), flight=flown.solo)


def first_forecast(mission: "Mission", routes: "Mapping[str, Route]", budget: "Budget | None" = None) -> TimedRoute:
    """Where the first vehicle in priority will be, and when, departing at t = 0, flown by the
    mission's variant: what the lower vehicles are planned against, and what the occlusion
    certificate judges (``coordination.forecast``: flown alone headless, or its sparse route at
    cruise). A vehicle alone is planned against nobody: its route at cruise. ``budget``: charged
    a unit per tick flown."""
    return vehicle_forecast(mission, routes, mission.by_priority[0].name, budget)


def vehicle_forecast(mission: "Mission", routes: "Mapping[str, Route]", name: str,
                     budget: "Budget | None" = None) -> TimedRoute:
    """Vehicle ``name`` forecast as :func:`first_forecast` forecasts the first: departing at
    t = 0 and flying undisturbed (the higher vehicle of a sight-line pair, for its certificate)."""
    if len(mission.vehicles) > 1 and mission.coordination.forecast is Forecast.FLOWN:
        return flown_forecast(mission, routes[name], name, budget)
    return route_forecast(mission, routes, name)


def mission_certificate(mission: "Mission", routes: "Mapping[str, Route] | None" = None,
                        budget: "Budget | None" = None, *, first: TimedRoute | None = None
                        ) -> OcclusionCertificate | None:
    """The headline of :func:`mission_certificates`: the first scored pair's certificate alone
    (None with a single vehicle or when its higher vehicle has no route)."""
    found = mission_certificates(mission, routes, budget, first=first, pairs=mission.sight_pairs[:1])
    return found[0] if found else None


def mission_certificates(mission: "Mission", routes: "Mapping[str, Route] | None" = None,
                         budget: "Budget | None" = None, *, first: TimedRoute | None = None,
                         pairs: "tuple[tuple[str, str], ...] | None" = None) -> tuple[OcclusionCertificate, ...]:
    """:func:`certify` of each scored pair (``pairs``, default ``Mission.sight_pairs``; the first
    is the headline), each against its higher vehicle's forecast as the mission's variant flies
    it (:func:`vehicle_forecast`): for the first vehicle ``first`` when the caller has it already
    (:func:`first_forecast` of these routes), else flown here within ``budget``, one flight per
    higher vehicle. The routes are planned when there are none (station-goal variants plan none).
    Empty with a single vehicle or when a higher vehicle has no route."""
    pairs = mission.sight_pairs if pairs is None else pairs
    if len(mission.vehicles) < 2 or not pairs:
        return ()
    top = mission.by_priority[0].name
    forecasts: dict[str, TimedRoute | None] = {} if first is None else {top: first}
    wanted = [high for high, _ in pairs if high not in forecasts]
    if wanted and (not routes or any(high not in routes for high in wanted)):
        try:
            routes = plan_routes(mission)
        except NoPath:
            return ()
    for high in dict.fromkeys(wanted):
        try:
            forecasts[high] = vehicle_forecast(mission, routes, high, budget)
        except BudgetSpent:
            forecasts[high] = None  # nothing is decided within the budget
    return tuple(certify(mission, forecasts[high], pair=(high, low), budget=budget) for high, low in pairs)
