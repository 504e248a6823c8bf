"""The unicycle, integrated once: constant (forward speed, yaw rate) per rollout, yaw first.

The plant (:mod:`uav_model.plant`) advances yaw first and then moves along the *new* heading, so
a constant (speed, yaw rate) command flown from cruise speed traces exactly these points; the
planner's rollouts are placed copies of them. Body frame: origin at the pose, heading along +x,
math angles (CCW positive), metres.
"""

from __future__ import annotations

import numpy as np


def body_rollouts(speeds_m_s: np.ndarray | float, yaw_rates_rad_s: np.ndarray, dt_s: float,
                  steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Points (S, K + 1, 2) at t = 0, dt, ..., K dt (the first is the origin) and the heading
    change (S, K) after each step, for S (speed, yaw rate) pairs held constant.

    ``speeds_m_s`` is one speed for all or one per yaw rate (S,). Vectorised: the heading is a
    cumulative product of rate and time, then cos/sin, then positions are accumulated (MPPI's
    batch shape)."""
    w = np.asarray(yaw_rates_rad_s, dtype=float)
    t = dt_s * np.arange(1, steps + 1)
    dheading = np.outer(w, t)
    step_m = np.asarray(speeds_m_s, dtype=float) * dt_s
    if step_m.ndim:
        step_m = step_m[:, None]
    body = np.zeros((len(w), steps + 1, 2))
    body[:, 1:, 0] = np.cumsum(np.cos(dheading), axis=1) * step_m
    body[:, 1:, 1] = np.cumsum(np.sin(dheading), axis=1) * step_m
    return body, dheading
