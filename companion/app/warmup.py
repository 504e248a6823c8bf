"""Load the planner's compiled kernels before anything flies.

With numba installed (the ``fast`` extra), a kernel's first call in a process loads its machine
code from the on-disk cache, or compiles it when the cache is missing or stale: about 1 s of CPU
from the cache and 4-5 s to compile (measured on tests/data/small_swap.yaml). The live pilot's
first tick runs at departure, on the event loop, so that second was spent in flight: on a busy
machine, at 20x, the loop stood still for 5-10 s of wall time (100-200 s of sim time) while the
vehicles hovered on their last setpoint, and telemetry came back stale and late. One throwaway
tick per vehicle before connecting pays it while nothing is armed.
"""

from __future__ import annotations

import math
import time

from companion.app.flight_plan import FlightPlan
from companion.app.steering import clearance_here_m
from companion.planning.dwa import OtherUav, Pose
from companion.planning.fleet import Neighbour, react_to
from companion.planning.obstacle_field import ObstacleField


def warm_up_planners(plan: FlightPlan) -> float:
    """One tick of a throwaway planner per vehicle, at its station, with the obstacles as the
    flight's first tick sees them (from tracks, as the ADS-B reports give them) and every other
    vehicle at its station; a vehicle whose sightline term acts only near the others (a timed
    route's ``sight_near_m``) ticks once more with them that near. Returns the wall seconds it took."""
    started = time.monotonic()
    mission = plan.mission
    field = ObstacleField.from_world(mission.world)
    snapshot = field.from_tracks(field.tracks_at(0.0))
    order = mission.by_priority
    planners = plan.fleet().planners  # throwaway: the flight builds its own
    for rank, spec in enumerate(order):
        planner = planners[spec.name]
        x, y = spec.start_enu_m
        near = planner.sight_near_m  # the sightline term acts only this near: warm it up there too
        for within_m in (math.inf,) if near is None else (math.inf, near / 2.0):
            others = [Neighbour(o.name, i, OtherUav(*_toward((x, y), o.start_enu_m, within_m), 0.0, 0.0))
                      for i, o in enumerate(order) if o.name != spec.name]
            reaction = react_to(x, y, rank, others)
            planner.tick(Pose(x, y, spec.initial_heading_rad), reaction.other, snapshot, 0.0, 0.0,
                         separate_from=reaction.separate_from)
        clearance_here_m(x, y, snapshot)  # the flight log's clearance: the kernels with other argument types
    return time.monotonic() - started


def _toward(own: tuple[float, float], other: tuple[float, float], within_m: float) -> tuple[float, float]:
    """``other`` moved toward ``own`` until it is at most ``within_m`` away."""
    d = math.hypot(other[0] - own[0], other[1] - own[1])
    f = 1.0 if d <= within_m else within_m / d
    return own[0] + (other[0] - own[0]) * f, own[1] + (other[1] - own[1]) * f
