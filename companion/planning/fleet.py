"""Which other vehicle one vehicle's planner reacts to, when more than two fly (issue 15).

The BDWA step (:func:`companion.planning.dwa.plan_step`) takes one other UAV: it keeps the
separation from it and, for every vehicle but the first in priority, scores the sightline to it.
With N vehicles the choice, made every tick, is by safety first and then by priority:

1. the nearest vehicle whose predicted path can come within the separation of a rollout
   (the same reach test as ``plan_step``'s): separation is a success criterion;
2. otherwise the nearest vehicle of higher priority: the paper's lower-priority UAV hides from
   the prioritised one, so each vehicle hides from the nearest vehicle that has right of way
   over it;
3. otherwise (the first in priority, or nobody of higher priority still flying) the nearest one.

With two vehicles every rule picks the one other vehicle, so two-vehicle flights are unchanged.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from companion.planning.dwa import DwaConfig, OtherUav


@dataclass(frozen=True, slots=True)
class Neighbour:
    """Another vehicle as this one sees it: its priority rank (0 = first) and its state."""

    name: str
    rank: int
    uav: OtherUav


def separation_can_bind(x_m: float, y_m: float, other: OtherUav, config: DwaConfig) -> bool:
    """Whether ``other``'s predicted path can come within the separation of a rollout from (x, y)."""
    reach = (config.reach_m + config.min_separation_m
             + math.hypot(other.vx_m_s, other.vy_m_s) * config.horizon_s + 1.0)
    return math.hypot(x_m - other.x_m, y_m - other.y_m) <= reach


def choose_other(x_m: float, y_m: float, rank: int, neighbours: Sequence[Neighbour],
                 config: DwaConfig) -> Neighbour | None:
    """The neighbour the planner of the vehicle at (x, y) with priority ``rank`` reacts to."""
    if not neighbours:
        return None
    if len(neighbours) == 1:
        return neighbours[0]
    by_distance = sorted(neighbours, key=lambda n: (math.hypot(n.uav.x_m - x_m, n.uav.y_m - y_m), n.rank))
    nearest = by_distance[0]
    if config.min_separation_m > 0 and separation_can_bind(x_m, y_m, nearest.uav, config):
        return nearest
    for n in by_distance:
        if n.rank < rank and not n.uav.arrived:
            return n
    return nearest
