"""The DWA's one seam between numpy and compiled code: a :class:`Backend` is the table of the
kernels a tick calls, and a :class:`.DwaConfig` holds one, chosen when the config is built.

    NUMPY      every kernel as numpy (the reference; what runs without the ``fast`` extra)
    COMPILED   each kernel's compiled twin (numba; None when numba is not installed)
    DEFAULT    COMPILED when numba is installed, else NUMPY

Each row pairs a numpy function with its twin, which lives beside it (``geometry`` and
``geometry_jit``, ``heading`` and ``heading_jit``, ...). The twins compute the same bits (see
:mod:`.jit`), so the backend decides the speed, never the command: ``tests/planning/test_kernels*.py``
holds each pair to that, and ``DwaConfig(..., backend=NUMPY)`` runs a whole tick on numpy
beside the compiled one.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from companion.planning.dwa import distance, evaluate, geometry, heading, recovery, sightline, sightline_slope
from companion.planning.dwa.snapshot import Culled, ObstacleSnapshot

try:
    from companion.planning.dwa import (distance_jit, evaluate_jit, geometry_jit, heading_jit, recovery_jit,
                                        sightline_jit)
except ImportError:  # numba is the ``fast`` extra: the numpy kernels run
    distance_jit = evaluate_jit = geometry_jit = heading_jit = recovery_jit = sightline_jit = None


@dataclass(frozen=True)
class Backend:
    """The kernels of one tick; see each numpy function for what it computes.

    ``obstacle_rule``, ``pick`` and ``pick_goals`` are where the compiled backend fuses several kernels into
    one call (a compiled call costs microseconds before it does anything); their numpy rows
    call the numpy kernels in turn."""

    name: str
    inflated_clearance: Callable = geometry.inflated_clearance
    polygon_signed_distance: Callable = geometry.polygon_signed_distance
    near_mask: Callable = ObstacleSnapshot.near_mask
    heading_from_ends: Callable = heading.heading_from_ends
    obstacle_and_distance: Callable = distance.obstacle_and_distance
    obstacle_rule: Callable = distance.obstacle_rule
    sightline_depths: Callable = sightline.sightline_depths
    open_clearance: Callable = sightline_slope.open_clearance
    choose: Callable = evaluate.choose
    pick: Callable = evaluate.pick
    pick_goals: Callable = evaluate.pick_goals
    spin_checks: Callable = recovery.spin_checks
    braking_checks: Callable = recovery.braking_checks

    def cull(self, snapshot: ObstacleSnapshot, x_m: float, y_m: float, reach_m: float, horizon_s: float,
             to_xy: tuple[float, float] | None = None) -> Culled:
        """The obstacles that can come within ``reach_m`` of (x, y) (of the segment to ``to_xy``)
        during ``horizon_s`` (see :meth:`.ObstacleSnapshot.near_mask`)."""
        keep, count = self.near_mask(snapshot, x_m, y_m, reach_m, horizon_s, to_xy)
        return Culled(snapshot, keep, count)

    def near(self, snapshot: ObstacleSnapshot, x_m: float, y_m: float, reach_m: float, horizon_s: float,
             to_xy: tuple[float, float] | None = None) -> ObstacleSnapshot:
        """:meth:`.ObstacleSnapshot.near` with this backend's culling."""
        return self.cull(snapshot, x_m, y_m, reach_m, horizon_s, to_xy).subset()

    def heading_scores(self, pts: np.ndarray, final_heading: np.ndarray, goals,
                       rows: np.ndarray | None = None) -> np.ndarray:
        """:func:`.heading.heading_scores` with this backend's critic; ``rows``: those rollouts'
        only (0 elsewhere), each the same as among all (a rollout's score is its own, once
        whether they all go for the first goal is settled over all of them)."""
        ex, ey, origin = pts[:, -1, 0], pts[:, -1, 1], pts[0, 0]
        if rows is None:
            return self.heading_from_ends(ex, ey, final_heading, goals, origin, pts[..., 0], pts[..., 1])
        single = heading.resolve_single(ex, ey, goals, origin, None)
        scores = np.zeros(len(pts))
        scores[rows] = self.heading_from_ends(ex[rows], ey[rows], final_heading[rows], goals, origin, pts[rows, :, 0],
                                              pts[rows, :, 1], single)
        return scores


NUMPY = Backend("numpy")

COMPILED = None if geometry_jit is None else Backend(
    "numba",
    inflated_clearance=geometry_jit.inflated_clearance,
    polygon_signed_distance=geometry_jit.polygon_signed_distance,
    near_mask=geometry_jit.near_mask,
    heading_from_ends=heading_jit.heading_from_ends,
    obstacle_and_distance=distance_jit.obstacle_and_distance,
    obstacle_rule=distance_jit.obstacle_rule,
    sightline_depths=sightline_jit.sightline_depths,
    open_clearance=sightline_jit.open_clearance,
    choose=evaluate_jit.choose,
    pick=evaluate_jit.pick,
    pick_goals=evaluate_jit.pick_goals,
    spin_checks=recovery_jit.spin_checks,
    braking_checks=recovery_jit.braking_checks,
)

DEFAULT = NUMPY if COMPILED is None else COMPILED
