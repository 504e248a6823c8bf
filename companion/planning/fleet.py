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

import numpy as np

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



class FleetView:
    """:func:`react_to` for every vehicle of a fleet in one tick, from one distance matrix.

    Vehicle i is at ``xy_m[i]`` (V, 2), seen by the others as ``uavs[i]``, named ``names[i]``, of
    priority rank i (``names`` in priority order), assigned ``partners[i]``. Each separation set
    leaves out the UAVs that cannot bind: those farther than ``reach[i]``'s metres plus their
    speed times its seconds (:func:`.dwa.legality.separation_reach`)."""

    def __init__(self, xy_m: Sequence[tuple[float, float]] | np.ndarray, uavs: Sequence[OtherUav],
                 names: Sequence[str], partners: Sequence[Collection[str] | None], reach: Sequence[tuple[float, float]]):
        self.uavs, self.names, self.partners, self.reach = list(uavs), names, partners, reach
        if len(self.uavs) == 2:  # a pair (the paper's case, most flights): no matrix
            return
        self.speed = np.array([math.hypot(u.vx_m_s, u.vy_m_s) for u in uavs])
        xy_m = np.asarray(xy_m)
        self.gap = np.hypot(xy_m[:, None, 0] - xy_m[None, :, 0], xy_m[:, None, 1] - xy_m[None, :, 1])
        self.flying = np.array([not u.arrived for u in uavs])
        self.ranks = np.arange(len(uavs))
        self.with_way = [u if u.arrived else OtherUav(u.x_m, u.y_m, u.vx_m_s, u.vy_m_s, False, True) for u in uavs]

    def park(self, i: int) -> None:
        """Vehicle i has arrived this tick: the others see it parked at its place."""
        u = self.uavs[i]
        self.uavs[i] = OtherUav(u.x_m, u.y_m, 0.0, 0.0, arrived=True)
        if len(self.uavs) > 2:
            self.speed[i] = 0.0
            self.with_way[i], self.flying[i] = self.uavs[i], False

    def alone(self, i: int) -> bool:
        """Whether no other vehicle can bind vehicle i's separation rule now (all out of its
        reach): i then decides as it would flying alone."""
        if len(self.uavs) == 2:
            me, you = self.uavs[i], self.uavs[1 - i]
            speed = math.hypot(you.vx_m_s, you.vy_m_s)
            return math.hypot(you.x_m - me.x_m, you.y_m - me.y_m) > self.reach[i][0] + speed * self.reach[i][1]
        return not self._near(i).size

    def _near(self, i: int) -> np.ndarray:
        """The others within vehicle i's separation reach (more than two vehicles)."""
        return np.flatnonzero((self.ranks != i) & (self.gap[i] <= self.reach[i][0] + self.speed * self.reach[i][1]))

    def reaction(self, i: int) -> Reaction:
        if len(self.uavs) == 2:  # a pair, as react_to answers it: the other is the partner and the separation set
            j = 1 - i
            return Reaction(Neighbour(self.names[j], j, self.uavs[j]), (self.uavs[j],))
        count, ranks = len(self.uavs), self.ranks
        others = pool = ranks != i
        if self.partners[i]:
            assigned = others & np.array([n in self.partners[i] for n in self.names])
            if assigned.any():
                pool = assigned
        above = pool & self.flying & (ranks < (i if pool is others else count))  # assigned: all count as above
        j = int(np.argmin(np.where(above if above.any() else pool, self.gap[i], np.inf)))  # ties: the lower rank
        near = self._near(i)
        if count > 2:  # react_to's right of way
            separate = tuple(self.with_way[k] if k < i else self.uavs[k] for k in near)
        else:
            separate = tuple(self.uavs[k] for k in near)
        return Reaction(Neighbour(self.names[j], j, self.uavs[j]), separate)
