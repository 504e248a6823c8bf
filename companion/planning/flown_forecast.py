"""The first vehicle's forecast as it will fly: its own planner on the mission's plant, alone.

The lower vehicles are planned in (position, time) against a forecast of the first
(:mod:`coordination`). A forecast along its sparse route at cruise can be 80-110 m off where the
multicopter really flies (it rounds the route's corners and keeps its distance from the
obstacles), so b, planned to hide behind an obstacle from that forecast, meets the real one
elsewhere with the line open. Flown alone headless first, with the runner that flies the
mission (:func:`runner.simulate`), the forecast is 5-25 m off. The lower vehicles change the
first one's flight only through the separation rule, which binds only when they meet.

The default (``coordination.forecast: flown``). Pure and deterministic: no I/O. It costs one headless
flight of one vehicle.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

from companion.planning.timed import TimedRoute

if TYPE_CHECKING:
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
    from companion.planning.runner import simulate  # the runner builds fleets, which plan with this module

    vehicle = mission.vehicle(name)
    alone = dataclasses.replace(mission, vehicles=(vehicle,))
    # Only the track is wanted: no lower bound to score it against (on a large mission that
    # bound's visibility graph costs more than the flight, and no budget meters it).
    track = simulate(alone, routes={name: route}, lower_bounds_s={name: None}, budget=budget).tracks[name]
    t, xy = np.asarray(track.t_s, dtype=float), np.column_stack([track.x_m, track.y_m])
    keep = np.zeros(len(t), dtype=bool)
    keep[::_EVERY] = True
    keep[-1] = True
    t, xy = t[keep], xy[keep]
    goal = np.asarray(vehicle.goal_enu_m, dtype=float)
    t = np.append(t, t[-1] + float(np.hypot(*(goal - xy[-1]))) / vehicle.speed_m_s)
    return TimedRoute(name, t, np.vstack([xy, goal]))
