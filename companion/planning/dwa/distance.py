"""The distance critic D: each rollout's smallest clearance to the inflated obstacles (moving ones
predicted at constant velocity), saturated at ``distance_saturation_m`` (see :class:`DwaConfig`)."""

from __future__ import annotations

import numpy as np

from companion.planning.dwa.config import DwaConfig


def distance_scores(lowest: np.ndarray, shape: tuple[int, int], config: DwaConfig) -> np.ndarray:
    """D (S,) from the clearance of every rollout point to its nearest inflated obstacle,
    ``lowest`` (S * (K + 1),); the pose itself (column 0) does not count."""
    return np.minimum(np.maximum(lowest.reshape(shape)[:, 1:].min(axis=1), 0.0), config.distance_saturation_m)


def no_obstacle_in_reach(config: DwaConfig) -> np.ndarray:
    """D when no obstacle is within reach: saturated for every rollout (the evaluation knows this
    row by identity and normalises it without summing)."""
    return config.saturated_m
