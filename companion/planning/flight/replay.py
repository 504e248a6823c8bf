"""A vehicle's flight alone, recorded tick by tick, and replayed where the fleet's flight repeats it.

A certified flight of a pair or a fleet begins with the first vehicle in priority flown alone
(its forecast: :mod:`forecast`), and the first vehicle then flies the mission again with the others.
It reacts to them through its separation rule only (it hides from nobody), and that rule cannot
bind while every other vehicle is out of its reach (:func:`.dwa.legality.separation_reach`). Until
then it decides, tick by tick, what it decided alone: the runner (:func:`loop.fly`) reads those
decisions back instead of deciding them again. When another vehicle comes within reach, its
planner first catches up on the ticks read, from the states and decisions recorded
(:meth:`SoloFlight.catch_up`: it follows them, :meth:`VehiclePlanner.follow`, without deciding),
so that it holds what it would have held, and decides while anyone is within reach. Once nobody
is, if the separation rule never changed a decision, it is still where it flew alone and is read
back again. The timed variant's first vehicle tracks what its solo flight tracked (its route at
cruise), paced by the forecast made of that flight, which a flight that is the forecast never
outruns (:meth:`SoloFlight.replays` checks it tick by tick); after a departure hold it is another
flight (:func:`solo_key` differs).

    fly(alone, fleet, routes, record="a").solo          # the forecast's flight (forecast.py)
    solo.replays(mission, "a", planners["a"], dt_s)     # the same vehicle, planner and world?
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from companion.planning.dwa import Pose
from companion.planning.timed_route import TimedRoute
from companion.planning.variants import VARIANTS, VariantSpec
from companion.planning.vehicle_planner import PACE_LEAD_M
from uav_model.frames import ned_to_enu, ned_yaw_to_enu_heading

if TYPE_CHECKING:
    from uav_model.mission import Mission
    from uav_model.plant import KinematicState
    from companion.planning.dwa import ObstacleSnapshot, OtherUav
    from companion.planning.obstacle_field import ObstacleField
    from companion.planning.vehicle_planner import TickResult, VehiclePlanner


def pose_of(state: "KinematicState") -> Pose:
    """The plant's state as its planner is given it: ENU position, heading and velocity."""
    x, y, _ = ned_to_enu(state.north_m, state.east_m)
    vx, vy, _ = ned_to_enu(state.vn_m_s, state.ve_m_s)
    return Pose(x, y, ned_yaw_to_enu_heading(state.yaw_rad), vx, vy)


def decide(planner: "VehiclePlanner", pose: "Pose", other: "OtherUav | None", snapshot: "ObstacleSnapshot",
           t_s: float, schedule_t_s: float | None, separate_from) -> "TickResult":
    """One vehicle's tick in the headless runner: its planner's decision, then a new route from
    here at once when it made no progress for a while."""
    result = planner.tick(pose, other, snapshot, t_s, separate_from=separate_from, schedule_t_s=schedule_t_s)
    _detour(planner, pose, t_s)
    return result


def _detour(planner: "VehiclePlanner", pose: "Pose", t_s: float) -> None:
    if planner.detour_due:
        planner.adopt_detour(planner.plan_detour(pose.x_m, pose.y_m), pose.x_m, pose.y_m, t_s)


def forecast_key(mission: "Mission") -> VariantSpec:
    """What of the mission's variant its first vehicle's forecast depends on: the variant
    without its sightline term, which the first in priority never flies with
    (:meth:`VehiclePlanner.build`). Two variants with one key (``bdwa`` and ``dwa``) forecast the
    same flight of the same mission, so a caller flying several may fly it once."""
    return dataclasses.replace(VARIANTS[mission.planner.variant], sightline=False, sightline_gain=1.0)


def solo_key(mission: "Mission", name: str, planner: "VehiclePlanner") -> tuple:
    """What vehicle ``name``'s decisions depend on, flown alone: the mission with it alone (its
    variant's name left out), the variant as it flies it (:func:`forecast_key`: ``bdwa`` and
    ``dwa`` fly the first vehicle alike), whether its planner carries the sightline term, its
    goals, and the timed route it tracks."""
    alone = dataclasses.replace(mission, vehicles=(mission.vehicle(name),), assigned_pairs=None,
                                planner=dataclasses.replace(mission.planner, variant=""))
    timed = planner.timed_route
    return (alone, forecast_key(mission), planner.config.w_s, planner.sight_near_m, planner.tracker.nodes.tobytes(),
            None if timed is None else (timed.t_s.tobytes(), timed.xy_enu_m.tobytes()))


@dataclass(frozen=True, eq=False)
class SoloFlight:
    """Vehicle ``vehicle`` flown alone (:func:`loop.fly` with ``record``): per tick, its plant's
    state (its planner was given :func:`pose_of` it), what it decided, and how many detours it had
    planned by then."""

    vehicle: str
    key: tuple  # solo_key of the flight
    states: tuple["KinematicState", ...]
    results: tuple["TickResult", ...]
    detours: tuple[int, ...]

    def replays(self, mission: "Mission", name: str, planner: "VehiclePlanner", dt_s: float) -> bool:
        """Whether ``name``, flown by ``planner`` in ``mission``, decides alone what this flight
        did: the same key, and, for a planner with a pace (the timed variant's first vehicle,
        paced by this very flight), never as far ahead of it as the pace would act on at ``dt_s``
        a tick (schedule time is sim time for the first vehicle)."""
        if name != self.vehicle or solo_key(mission, name, planner) != self.key:
            return False
        pace = planner.pace
        if pace is None:
            return True
        poses = [pose_of(state) for state in self.states]  # as the planner's _schedule reads its pace, tick by tick
        return pace.first_lead_over([p.x_m for p in poses], [p.y_m for p in poses],
                                    dt_s * np.arange(len(poses)), PACE_LEAD_M) is None

    def catch_up(self, planner: "VehiclePlanner", start: int, stop: int, field: "ObstacleField", dt_s: float,
                 timed: bool) -> None:
        """Have ``planner`` (as this flight's was at tick ``start``) keep what it would have kept
        deciding ticks ``start`` to ``stop`` from the states recorded: what this flight's planner
        held then. It follows the decisions recorded (:meth:`VehiclePlanner.follow`) and decides
        again only a spin recovery's (its heading is kept). ``timed``: the runner reads a timed
        route (its clock is sim time for a vehicle alone)."""
        for k in range(start, stop):
            t = k * dt_s
            pose = pose_of(self.states[k])
            if planner.follow(pose, t, t if timed else None, self.results[k]):
                _detour(planner, pose, t)
            else:  # a spin recovery: decided again, among its obstacles then
                snapshot = next(field.at_times(dt_s * np.array([k], dtype=float)))
                decide(planner, pose, None, snapshot, t, t if timed else None, ())


class SoloRecorder:
    """Keeps one vehicle's flight tick by tick while :func:`loop.fly` flies it (``record``)."""

    def __init__(self, mission: "Mission", name: str, planner: "VehiclePlanner"):
        self.name, self.planner = name, planner
        self.key = solo_key(mission, name, planner)  # as built: a detour changes its goals later
        self.states: list["KinematicState"] = []
        self.detours: list[int] = []

    def add(self, state: "KinematicState") -> None:
        """The vehicle was in ``state`` this tick and has decided (its detours counted after)."""
        self.states.append(state)
        self.detours.append(self.planner.detours)

    def flight(self, results: "list[TickResult]") -> SoloFlight:
        """The flight kept, up to the ticks it was scored on (a run cut at a broken rule drops the rest)."""
        n = len(results)
        return SoloFlight(self.name, self.key, tuple(self.states[:n]), tuple(results), tuple(self.detours[:n]))


@dataclass(frozen=True, eq=False)
class FlownForecast(TimedRoute):
    """A forecast read from a vehicle's headless flight alone (:func:`forecast.flown_forecast`),
    with that flight, for the fleet's flight to replay (:attr:`FleetSetup.solo`)."""

    flight: SoloFlight | None = None
