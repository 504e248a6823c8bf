"""Load the planner's compiled kernels before anything flies.

With numba installed (the ``fast`` extra), a kernel's first call in a process loads its machine
code from the on-disk cache, or compiles it when the cache is missing or stale: about 1 s of CPU
from the cache and 4-5 s to compile (measured on tests/data/small_swap.yaml). The live pilot's
first tick runs at departure, on the event loop, so that second was spent in flight: on a busy
machine, at 20x, the loop stood still for 5-10 s of wall time (100-200 s of sim time) while the
vehicles hovered on their last setpoint, and telemetry came back stale and late. One throwaway
tick per vehicle before connecting pays it while nothing is armed. A headless ``simulate`` does
the same before its clock starts (:func:`warm_up_headless`), so its speed is the flight's, not
the loading's.
"""

from __future__ import annotations

import contextlib
import math
import time
from typing import TYPE_CHECKING

import numpy as np

from companion.app.flight_plan import FlightPlan
from companion.planning.budget import BudgetSpent, WorkBudget
from companion.planning.errors import NoPath
from companion.app.steering import clearance_here_m
from companion.planning.dwa import OtherUav, Pose
from companion.planning.dwa.backend import DEFAULT as DWA_KERNELS
from companion.planning.dwa.step import warm_up_kernels
from companion.planning.fleet import Neighbour, react_to
from companion.planning.obstacle_field import ObstacleField
from companion.planning.flight.headless import simulate
from companion.planning.timed_route import TimedRoute
from uav_model.mission import Mission

if TYPE_CHECKING:
    from companion.planning.routes import Route

_HEADLESS_WARM_TICKS = 3  # ticks of the throwaway flight: every vehicle plans against its route


def warm_up_headless(mission: Mission, variant: str | None = None, *,
                     inputs: tuple[dict[str, Route], TimedRoute | None] | None = None) -> float:
    """Load the compiled code a headless flight of ``mission`` with ``variant`` calls: the
    branches of :func:`warm_up_kernels`, then the first ticks of a throwaway flight (its routes,
    space-time plan, planners and plant). ``inputs``: the flight's routes and first vehicle's
    forecast (:func:`flight_inputs`), which the flight that follows uses too: without them the
    throwaway flight plans its own routes and flies the forecast, a whole flight of the first
    vehicle. Returns the wall seconds it took."""
    started = time.monotonic()
    warm_up_kernels()
    routes, first = (None, None) if inputs is None else inputs
    with contextlib.suppress(BudgetSpent, NoPath):  # NoPath: the flight itself says so
        simulate(mission, variant, routes=routes, first=first, budget=WorkBudget(_HEADLESS_WARM_TICKS))
    _warm_sloped_sightline(mission)
    return time.monotonic() - started


def _warm_sloped_sightline(mission: Mission) -> None:
    """The sloped sightline critic (timed variants) once the other vehicle is near, which the
    first ticks do not see, with the rollouts' ends as strided views and as arrays of their own
    (each another signature to the compiled code: left to the flight, one compiled 12 s of sim
    after departure)."""
    snapshot = ObstacleField.from_world(mission.world).at_time(0.0)
    for ends in (np.zeros((2, 2))[:, 0], np.zeros(2)):
        DWA_KERNELS.open_clearance(ends, ends, (5.0, 5.0), 1.0, snapshot)


def warm_up_planners(plan: FlightPlan) -> float:
    """One tick of a throwaway planner per vehicle, at its station, with the obstacles as the
    flight's first tick sees them (from tracks, as the ADS-B reports give them) and every other
    vehicle at its station, its sightline term on (with a timed route it acts only near the
    others in flight: ``sight_near_m``). Returns the wall seconds it took."""
    started = time.monotonic()
    warm_up_kernels()  # the branches a tick at the station may not take
    mission = plan.mission
    field = ObstacleField.from_world(mission.world)
    snapshot = field.from_tracks(field.tracks_at(0.0))
    order = mission.by_priority
    planners = plan.fleet_setup().planners  # throwaway: the flight builds its own
    for rank, spec in enumerate(order):
        planner = planners[spec.name]
        if planner.sight_near_m is not None:  # the term acts only near the others in flight, but
            planner.sight_near_m = math.inf   # its kernels are the same: load them here, from afar
        x, y = spec.start_enu_m
        others = [Neighbour(o.name, i, OtherUav(*o.start_enu_m, 0.0, 0.0))
                  for i, o in enumerate(order) if o.name != spec.name]
        reaction = react_to(x, y, rank, others, mission.hides_from(spec.name))
        planner.tick(Pose(x, y, spec.initial_heading_rad), reaction.other, snapshot, 0.0, 0.0,
                     separate_from=reaction.separate_from)
        clearance_here_m(x, y, snapshot)  # the flight log's clearance: the kernels with other argument types
    _warm_sloped_sightline(mission)
    # the schedule clocks' queries (timed variants), which the flight's context asks every tick:
    # the reach, and a lower vehicle's progress along its plan (the re-plan's watch)
    warm = TimedRoute("warm", np.array([0.0, 1.0]), np.zeros((2, 2)))
    warm.latest_near_s((0.0, 0.0), 0.0, np.zeros(1), 1.0)
    warm.progress_of(0.0, 0.0, 0.0)
    return time.monotonic() - started
