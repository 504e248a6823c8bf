"""The distance critic D: each rollout's smallest clearance to the inflated obstacles (moving ones
predicted at constant velocity), saturated at ``distance_saturation_m`` (see :class:`DwaConfig`)."""

from __future__ import annotations

import numpy as np

from companion.planning.dwa import kernels
from companion.planning.dwa.config import DwaConfig
from companion.planning.dwa.geometry import one_layout
from companion.planning.dwa.legality import obstacle_ok


def obstacle_and_distance(clear: np.ndarray, shape: tuple[int, int],
                          saturation_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The obstacle rule per rollout point (S * (K + 1),) (:func:`legality.obstacle_ok`) and D
    (S,) from the clearances (O, S * (K + 1)) of rollouts of ``shape`` (S, K + 1), O >= 1: each
    rollout's nearest clearance after the pose (column 0 does not count), in [0, saturation_m].
    With numba, one compiled pass (:func:`kernels.obstacle_terms`)."""
    if kernels.obstacle_terms is not None:
        return kernels.obstacle_terms(one_layout(clear), int(shape[1]), float(saturation_m))
    lowest = clear.min(axis=0)
    distance = np.minimum(np.maximum(lowest.reshape(shape)[:, 1:].min(axis=1), 0.0), saturation_m)
    return obstacle_ok(clear, lowest), distance


def no_obstacle_in_reach(config: DwaConfig) -> np.ndarray:
    """D when no obstacle is within reach: saturated for every rollout (the evaluation knows this
    row by identity and normalises it without summing)."""
    return config.saturated_m
