"""The paper's unicycle: one pure kinematic step, the plant the paper's tables were flown on.

Yaw follows the commanded yawspeed within the yaw-rate limit; horizontal velocity moves toward
the setpoint within the acceleration limit and is capped at the speed limit; altitude follows a
climb-rate setpoint within its own limits. The yaw is advanced first and a body-frame setpoint is
rotated by the *new* yaw, so a constant (forward speed, yaw rate) command traces exactly the
unicycle the planner's rollouts assume: :func:`body_rollouts`, the same integration vectorised
over a batch of (speed, yaw rate) pairs, is what the planner's rollout shapes are built from.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uav_model.plant.state import HOVER, KinematicState, VelocityCommand, VelocityFrame


@dataclass(frozen=True, slots=True)
class VehicleLimits:
    max_speed_m_s: float
    max_yaw_rate_rad_s: float
    max_accel_m_s2: float
    max_climb_m_s: float = 3.0
    max_alt_m: float = 500.0  # above home

    @property
    def yaw_p_1_s(self) -> float:
        """Yaw-angle gain an autopilot can use: the unicycle turns at once, so any (dead-beat)."""
        return math.inf

    @property
    def yaw_lag_s(self) -> float:
        """How long the heading rate takes to follow its setpoint: no time at all."""
        return 0.0


def _clip(value: float, limit: float) -> float:
    return max(-limit, min(limit, value))


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def step(state: KinematicState, command: VelocityCommand, limits: VehicleLimits, dt_s: float) -> KinematicState:
    """Advance the plant by ``dt_s`` seconds under ``command``. Pure; non-finite commands hover."""
    isfinite = math.isfinite
    if not (isfinite(command.x_m_s) and isfinite(command.y_m_s) and isfinite(command.z_m_s)
            and isfinite(command.yawspeed_rad_s)):
        command = HOVER
    yawspeed = _clip(command.yawspeed_rad_s, limits.max_yaw_rate_rad_s)
    yaw = _wrap(state.yaw_rad + yawspeed * dt_s)

    if command.frame is VelocityFrame.BODY_NED:
        c, s = math.cos(yaw), math.sin(yaw)
        vn_sp = c * command.x_m_s - s * command.y_m_s
        ve_sp = s * command.x_m_s + c * command.y_m_s
    else:
        vn_sp, ve_sp = command.x_m_s, command.y_m_s
    speed_sp = math.hypot(vn_sp, ve_sp)
    if speed_sp > limits.max_speed_m_s:
        k = limits.max_speed_m_s / speed_sp
        vn_sp, ve_sp = vn_sp * k, ve_sp * k

    # Acceleration limit on the horizontal velocity change. A body-frame command that only
    # rotates the velocity (constant speed, turning) is a pure heading change, which the
    # turn-rate limit already bounds: it is not throttled here, as a fixed-speed turn is the
    # motion the planner commands.
    dvn, dve = vn_sp - state.vn_m_s, ve_sp - state.ve_m_s
    if command.frame is VelocityFrame.BODY_NED:
        old_speed = state.ground_speed_m_s
        new_speed = math.hypot(vn_sp, ve_sp)
        dspeed = _clip(new_speed - old_speed, limits.max_accel_m_s2 * dt_s)
        target_speed = old_speed + dspeed
        heading = math.atan2(ve_sp, vn_sp) if new_speed > 1e-9 else yaw
        vn, ve = target_speed * math.cos(heading), target_speed * math.sin(heading)
    else:
        dv = math.hypot(dvn, dve)
        max_dv = limits.max_accel_m_s2 * dt_s
        if dv > max_dv:
            dvn, dve = dvn * max_dv / dv, dve * max_dv / dv
        vn, ve = state.vn_m_s + dvn, state.ve_m_s + dve

    vd_sp = _clip(command.z_m_s, limits.max_climb_m_s)
    vd = state.vd_m_s + _clip(vd_sp - state.vd_m_s, limits.max_accel_m_s2 * dt_s)
    down = state.down_m + vd * dt_s
    down = min(0.0, max(-limits.max_alt_m, down))
    if down in (0.0, -limits.max_alt_m):
        vd = 0.0

    # Every field is new: the constructor, not dataclasses.replace (several times slower; this
    # runs once per vehicle per tick in the headless runner).
    return KinematicState(state.north_m + vn * dt_s, state.east_m + ve * dt_s, down, vn, ve, vd, yaw, yawspeed)


def body_rollouts(speeds_m_s: np.ndarray | float, yaw_rates_rad_s: np.ndarray, dt_s: float,
                  steps: int) -> tuple[np.ndarray, np.ndarray]:
    """The unicycle from rest at the origin, heading +x (math angles, metres), yaw first as in
    :func:`step`: points (S, K + 1, 2) at t = 0, dt, ..., K dt (the first is the origin) and the
    heading change (S, K) after each step, for S (speed, yaw rate) pairs held constant.

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
