"""The values a BDWA step takes and returns: own pose, the other UAV, the chosen command or
why there is none, and the local-goal window the heading critic scores toward."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass(frozen=True, slots=True)
class Pose:
    """Own state in the ENU mission frame; heading is a math angle (from +x, CCW)."""

    x_m: float
    y_m: float
    heading_rad: float
    # The velocity over ground (ENU, m/s), where the caller knows it: a plant that lags its
    # commands (DwaConfig.tracking_lag_s) carries it on. None: at cruise along the heading.
    vx_m_s: float | None = None
    vy_m_s: float | None = None

    def velocity_m_s(self, cruise_m_s: float) -> tuple[float, float]:
        """(vx, vy): the velocity given, else ``cruise_m_s`` along the heading."""
        if self.vx_m_s is None or self.vy_m_s is None:
            return cruise_m_s * math.cos(self.heading_rad), cruise_m_s * math.sin(self.heading_rad)
        return self.vx_m_s, self.vy_m_s


@dataclass(frozen=True, slots=True)
class OtherUav:
    """The other UAV as the link reports it; predicted at constant velocity."""

    x_m: float
    y_m: float
    vx_m_s: float
    vy_m_s: float
    arrived: bool = False  # parked at its station: still kept clear of, no longer hidden from
    # Has right of way over this vehicle (more than two flying: see companion.planning.fleet);
    # then kept clear of by ``DwaConfig.yield_margin_m`` more than the separation.
    right_of_way: bool = False


@dataclass(frozen=True, slots=True)
class Command:
    """The chosen first step: ENU yaw rate (CCW positive) at the constant forward speed."""

    yaw_rate_rad_s: float
    speed_m_s: float
    heading_score: float  # raw critic values of the chosen rollout, for logs
    distance_score: float
    sightline_score: float
    eval_score: float  # normalised, weighted total
    legal_count: int  # how many of the samples were legal


def slots_constructor(cls: type) -> Callable[..., Any]:
    """A function making ``cls(*values)`` for a frozen dataclass with slots, every field given in
    order, with the slots' own setters: the dataclass's ``__init__`` guards each assignment (a
    frozen instance refuses setattr), which costs twice as much, and every tick makes a Command
    and a tick result. Generated as the dataclass's own ``__init__`` is, one line per field."""
    names = cls.__slots__
    scope = {"new": object.__new__, "cls": cls, **{f"set_{n}": getattr(cls, n).__set__ for n in names}}
    lines = [f"def make({', '.join(names)}):", "    out = new(cls)", *(f"    set_{n}(out, {n})" for n in names),
             "    return out"]
    exec("\n".join(lines), scope)  # the code is made here, from the class's own field names
    return scope["make"]


make_command = slots_constructor(Command)  # Command(*values), every field given (the compiled picks)


@dataclass(frozen=True, slots=True)
class NoLegalRollout:
    """Every sampled rollout breaks a rule within the horizon. The vehicle holds (hovers) this
    tick, unless ``recovery`` is given (yaw in place toward a heading from which a rollout is
    legal: a Command with speed 0) or ``escape`` (a rollout that stays clear longer than
    hovering would, when the hover point is not safe). At most one of the two is set."""

    reason: str
    escape: Command | None = None
    recovery: Command | None = None
    turn_rad: float = 0.0  # with ``recovery``: the yaw in place it turns by (left positive)


@dataclass(frozen=True, eq=False)
class LocalGoals:
    """The current local goal and the nodes after it, for the heading critic.

    The paper scores the heading at the prediction point toward "the local goal". A rollout whose
    prediction point lies beyond the current node would then be rewarded for turning back to a
    node the vehicle is about to pass anyway: with p = 11 s (110 m ahead) and nodes that sit on
    the inflated edge, that is the "turning around in place" of the paper's Fig. 7. So each
    rollout is scored toward the goal the tracker would hold at its prediction point: a node
    counts as reached along the rollout when a rollout point comes within ``acceptance_radius_m``
    of it or the prediction point has passed it (the tracker's own two rules); the station,
    last, counts only within ``station_radius_m`` and then scores the full 180 deg.
    """

    nodes_xy: np.ndarray  # (G, 2): the current local goal first, then the ones after it
    prev_xy: tuple[float, float]  # the node before the current goal
    acceptance_radius_m: float
    station_radius_m: float
    ends_at_station: bool  # whether nodes_xy[-1] is the station

    # Derived once (a tracker reuses its windows across ticks): each node's predecessor and
    # squared reach radius, for heading_scores.
    prev_nodes_xy: np.ndarray = field(init=False, repr=False)  # (G, 2)
    radius2_m2: np.ndarray = field(init=False, repr=False)  # (G,)
    first_xy: tuple[float, float] = field(init=False, repr=False)  # nodes_xy[0] as floats

    def __post_init__(self) -> None:
        nodes = np.asarray(self.nodes_xy, dtype=float)
        radius = np.full(len(nodes), self.acceptance_radius_m)
        if self.ends_at_station:
            radius[-1] = self.station_radius_m
        object.__setattr__(self, "prev_nodes_xy", np.vstack([self.prev_xy, nodes[:-1]]))
        object.__setattr__(self, "radius2_m2", radius * radius)
        object.__setattr__(self, "first_xy", (float(nodes[0, 0]), float(nodes[0, 1])))

    @classmethod
    def along(cls, nodes_xy: np.ndarray, i: int, count: int, acceptance_radius_m: float,
              station_radius_m: float) -> "LocalGoals":
        """The window ``nodes_xy[i:i + count]`` of a route's nodes (float (N, 2), i >= 1), after
        ``nodes_xy[i - 1]``; what the constructor makes, its node arrays as views of the route's
        (a raw A* route's vehicle builds a window every other tick)."""
        nodes = nodes_xy[i:i + count]
        out = object.__new__(cls)
        radius = np.full(count, acceptance_radius_m)
        ends = i + count == len(nodes_xy)
        if ends:
            radius[-1] = station_radius_m
        out.__dict__.update(nodes_xy=nodes, prev_xy=(float(nodes_xy[i - 1, 0]), float(nodes_xy[i - 1, 1])),
                            acceptance_radius_m=acceptance_radius_m, station_radius_m=station_radius_m,
                            ends_at_station=ends, prev_nodes_xy=nodes_xy[i - 1:i - 1 + count],
                            radius2_m2=radius * radius, first_xy=(float(nodes[0, 0]), float(nodes[0, 1])))
        return out

    @classmethod
    def single(cls, goal_xy: tuple[float, float]) -> "LocalGoals":
        """One goal and nothing after it: the paper's heading critic exactly."""
        return cls(np.asarray([goal_xy], dtype=float), (float(goal_xy[0]), float(goal_xy[1])),
                   0.0, 0.0, ends_at_station=False)
