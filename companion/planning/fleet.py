"""Whom one vehicle's planner reacts to, when more than two fly.

The BDWA step (:func:`companion.planning.dwa.plan_step`) reacts to the other UAVs in two ways:

- *separation* (a legality rule): against **every** other vehicle whose predicted path can come
  within reach of a rollout, all of them in one array operation. Separation is a success
  criterion for every pair; keeping clear of one vehicle at a time lost it where eight routes
  meet (49-50 m < 50 m at the centre of the perimeter layout);
- *sightline* (a critic, for every vehicle but the first in priority): toward **one** partner,
  the nearest vehicle of higher priority still flying (the paper's lower-priority UAV hides
  from the prioritised one, so each vehicle hides from the nearest vehicle that has right of way
  over it); otherwise (the first in priority, or nobody of higher priority still flying) the
  nearest one.

With two vehicles both are the one other vehicle, so two-vehicle flights are unchanged.

A mission that assigns its sight-line pairs (``sightline.pairs``) replaces the partner rule: each
vehicle hides from the nearest of its assigned partners still flying (``Mission.hides_from``), and
a vehicle that hides from nobody flies without the term (``Mission.carries_sightline``).
"""

from __future__ import annotations

import math
from collections.abc import Collection, Sequence
from dataclasses import dataclass

from companion.planning.dwa import OtherUav


@dataclass(frozen=True, slots=True)
class Neighbour:
    """Another vehicle as this one sees it: its priority rank (0 = first) and its state."""

    name: str
    rank: int
    uav: OtherUav


@dataclass(frozen=True, slots=True)
class Reaction:
    """What one vehicle's planner takes this tick: the sightline partner and every UAV to keep
    separated from (the arguments ``other`` and ``separate_from`` of ``plan_step``)."""

    partner: Neighbour | None
    separate_from: tuple[OtherUav, ...]

    @property
    def other(self) -> OtherUav | None:
        return None if self.partner is None else self.partner.uav


def sightline_partner(x_m: float, y_m: float, rank: int, neighbours: Sequence[Neighbour],
                      partners: Collection[str] | None = None) -> Neighbour | None:
    """The neighbour the vehicle at (x, y) with priority ``rank`` hides from: the nearest one of
    higher priority still flying, else the nearest. ``partners`` (the names it is assigned to
    hide from; None: no assignment): the nearest of them still flying, else the nearest of them;
    with none of them in ``neighbours``, the rule without assignment (the term is off then)."""
    if partners:
        assigned = [n for n in neighbours if n.name in partners]
        if assigned:
            neighbours, rank = assigned, math.inf  # every assigned partner counts as above it
    if len(neighbours) <= 1:
        return neighbours[0] if neighbours else None

    def nearest(n: Neighbour) -> tuple[float, int]:
        return math.hypot(n.uav.x_m - x_m, n.uav.y_m - y_m), n.rank

    above = [n for n in neighbours if n.rank < rank and not n.uav.arrived]
    return min(above or neighbours, key=nearest)


def react_to(x_m: float, y_m: float, rank: int, neighbours: Sequence[Neighbour],
             partners: Collection[str] | None = None) -> Reaction:
    """The sightline partner and the separation set of the vehicle at (x, y) with ``rank``.

    With more than two vehicles, each one flying with higher priority is marked as having right
    of way (``OtherUav.right_of_way``: kept clear of by a margin more), so that of two vehicles
    meeting the lower-priority one gives way first. With two, the routes already keep the pair
    apart (the paper's opposite-side rule) and nobody is marked. ``partners``: as for
    :func:`sightline_partner`."""
    partner = sightline_partner(x_m, y_m, rank, neighbours, partners)
    if len(neighbours) < 2:
        return Reaction(partner, tuple(n.uav for n in neighbours))
    uavs = tuple(OtherUav(n.uav.x_m, n.uav.y_m, n.uav.vx_m_s, n.uav.vy_m_s, False, True)  # right of way
                 if n.rank < rank and not n.uav.arrived else n.uav for n in neighbours)
    return Reaction(partner, uavs)
