"""Coordinated timing: prioritised space-time planning that keeps the sight lines blocked.

Vehicles are planned in ``mission.by_priority`` order (the paper's rule, section III.A). The
first flies as its forecast has it (the caller's: :func:`companion.planning.flight.forecast.first_forecast`;
its planner tracks what the forecast flight tracked, paced by the forecast: :attr:`CoordinatedPlan.first_tracks`),
after a departure hold when the mission allows one (``coordination.hold_s_max``; the least that
keeps the line to the vehicle hiding from it blocked, found as the occlusion certificate finds it:
:func:`certificate.least_hold`). Every later vehicle is planned against the forecasts of all
vehicles above it, the strictest rule first (:func:`search.plan_vehicle`): it hides from all of
them, or from its assigned partners only when the mission assigns sight-line pairs (none: it is
planned for separation only), or flies its route at cruise speed when not even separation can be
planned (``planned`` False). The result records which rule held.

    first = first_forecast(mission, routes)            # flown once, by the caller
    plan = plan_coordinated(mission, routes, first)
    plan.timed["b"], plan.blocking["b"], plan.hold_s
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from companion.planning.coordination.certificate import hold_partner, least_hold
from companion.planning.coordination.search import Blocking, near_margin_m, plan_vehicle
from companion.planning.coordination.shadow import SightShadows
from companion.planning.coordination.timed import forecast, held
from companion.planning.grid import OccupancyGrid, rasterise
from companion.planning.timed_route import TimedRoute

if TYPE_CHECKING:
    from collections.abc import Mapping

    from uav_model.mission import Mission
    from companion.planning.routes import Route


@dataclass(frozen=True, eq=False)
class CoordinatedPlan:
    """Timed routes for every vehicle, the departure hold of the first, and what each achieved."""

    hold_s: float
    step_s: dict[str, float]
    timed: dict[str, TimedRoute]
    blocking: dict[str, Blocking]
    planned: dict[str, bool]  # False: no space-time plan at all, the route at cruise speed
    # What the first vehicle's planner tracks: its route at cruise after its hold, as its forecast
    # was flown (so that, headless, its flight is its forecast to the tick until another vehicle
    # comes within its separation reach, and is read back: flight.replay). It is paced by
    # ``timed`` (its forecast, held), which the others are planned and clocked against: it never
    # runs more than :data:`.vehicle_planner.PACE_LEAD_M` ahead of it (PX4 flies a corner faster than the plant
    # the forecast is flown on, and a running ahead of its forecast met b with the line open).
    first_tracks: TimedRoute | None = None

    def tracked(self, name: str) -> TimedRoute | None:
        """The timed route vehicle ``name``'s planner tracks (:attr:`first_tracks` for the first)."""
        if self.first_tracks is not None and name == self.first_tracks.vehicle:
            return self.first_tracks
        return self.timed.get(name)

    def paced(self, name: str) -> TimedRoute | None:
        """The plan vehicle ``name`` must not run ahead of, when it tracks another (the first: its forecast)."""
        return self.timed.get(name) if self.first_tracks is not None and name == self.first_tracks.vehicle else None


def departure_hold(mission: "Mission", first: TimedRoute, grid: OccupancyGrid, shadows: SightShadows,
                   memo: dict | None = None) -> float:
    """The least hold of the first vehicle within ``coordination.hold_s_max`` that lets the
    vehicle its hold is for (:func:`certificate.hold_partner`: the second in priority, or the
    first assigned to hide from it) keep the line blocked the whole flight, else at closest
    approach (with the margin of :func:`search.near_margin_m`, then without), else 0."""
    order, limit_s = mission.by_priority, mission.coordination.hold_s_max
    lower = hold_partner(mission) if len(order) >= 2 else None
    if lower is None or not limit_s > 0:
        return 0.0
    margin = near_margin_m(mission, lower, order[0].speed_m_s)
    for blocking, margin_m in ((Blocking.WHOLE_FLIGHT, 0.0), (Blocking.CLOSEST_APPROACH, margin),
                               (Blocking.CLOSEST_APPROACH, 0.0)):
        found = least_hold(mission, first, blocking, limit_s, grid, shadows, memo, margin_m, lower=lower)
        if found is not None:
            return found
    return 0.0


def plan_coordinated(mission: "Mission", routes: "Mapping[str, Route]", first: TimedRoute, *,
                     hold_s: float | None = None, grid: OccupancyGrid | None = None,
                     shadows: SightShadows | None = None) -> CoordinatedPlan:
    """Timed routes for every vehicle (see the module doc) against ``first``, the first
    vehicle's forecast without a hold. ``hold_s``: its departure hold; by default
    :func:`departure_hold`."""
    order = mission.by_priority
    if len(order) > 1:  # alone (a forecast's flight), nobody is planned in space and time
        grid = grid or rasterise(mission.world, mission.planner.grid_resolution_m)
        shadows = shadows or SightShadows(mission.world, grid)
    top = order[0]
    memo: dict = {}
    if hold_s is None:
        hold_s = departure_hold(mission, first, grid, shadows, memo)
    timed = {top.name: held(first, hold_s)}
    blocking = {top.name: Blocking.WHOLE_FLIGHT}
    planned = {top.name: True}
    steps = {top.name: 0.0}
    for v in order[1:]:
        found = plan_vehicle(mission, v.name, tuple(timed.values()), grid, shadows, memo)
        if found is not None:
            timed[v.name], blocking[v.name], steps[v.name] = found
            planned[v.name] = True
        else:
            timed[v.name] = forecast(v.name, routes[v.name].sparse_enu_m, v.speed_m_s)
            blocking[v.name], planned[v.name], steps[v.name] = Blocking.NONE, False, 0.0
    cruise = route_forecast(mission, routes)  # what the first's forecast flight tracked (none to pace: it is that)
    same = np.array_equal(cruise.t_s, first.t_s) and np.array_equal(cruise.xy_enu_m, first.xy_enu_m)
    return CoordinatedPlan(hold_s, steps, timed, blocking, planned, None if same else held(cruise, hold_s))


def route_forecast(mission: "Mission", routes: "Mapping[str, Route]", name: str | None = None) -> TimedRoute:
    """Vehicle ``name`` (default: the first in priority) along its sparse A* route at cruise,
    departing at t = 0 (``coordination.forecast: route``, and any vehicle flown alone)."""
    v = mission.vehicle(name) if name is not None else mission.by_priority[0]
    return forecast(v.name, routes[v.name].sparse_enu_m, v.speed_m_s)
