"""The distance critic D: each rollout's smallest clearance to the inflated obstacles (moving ones
predicted at constant velocity), saturated at ``distance_saturation_m`` (see :class:`DwaConfig`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from companion.planning.dwa.geometry import inflated_clearance
from companion.planning.dwa.legality import obstacle_ok

if TYPE_CHECKING:
    from companion.planning.dwa.config import DwaConfig
    from companion.planning.dwa.snapshot import Culled


def obstacle_and_distance(clear: np.ndarray, shape: tuple[int, int],
                          saturation_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The obstacle rule per rollout point (S * (K + 1),) (:func:`legality.obstacle_ok`) and D
    (S,) from the clearances (O, S * (K + 1)) of rollouts of ``shape`` (S, K + 1), O >= 1: each
    rollout's nearest clearance after the pose (column 0 does not count), in [0, saturation_m]."""
    lowest = clear.min(axis=0)
    distance = np.minimum(np.maximum(lowest.reshape(shape)[:, 1:].min(axis=1), 0.0), saturation_m)
    return obstacle_ok(clear, lowest), distance


def obstacle_rule(px: np.ndarray, py: np.ndarray, culled: Culled, config: DwaConfig,
                  times_s: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, None]:
    """The clearances (O, S * (K + 1)) of the rollouts (px, py) (S, K + 1) to the obstacles
    ``culled`` keeps, the obstacle rule (S, K + 1), D (S,), and the rule per rollout: None here
    (:func:`.legality.legal_rollouts` works it out; the compiled twin returns it). ``times_s``:
    the points' times (default ``config.point_times_s``, every rollout of the window; the
    distinct rollouts pass ``config.geo_point_times_s``)."""
    shape = px.shape
    times_s = config.point_times_s if times_s is None else times_s
    clear = inflated_clearance(px.ravel(), py.ravel(), times_s, culled.subset())
    ok, distance = obstacle_and_distance(clear, shape, config.distance_saturation_m)
    return clear, ok.reshape(shape), distance, None


def no_obstacle_in_reach(config: DwaConfig) -> np.ndarray:
    """D when no obstacle is within reach: saturated for every rollout (the evaluation knows this
    row by identity and normalises it without summing)."""
    return config.saturated_m
