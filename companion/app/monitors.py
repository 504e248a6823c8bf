"""Safety monitors: pure checks the runner applies to every command before it is sent.

They are a backstop behind the planner, not a second planner: each looks a few seconds ahead
with the simplest model that is safe to trust (the commanded unicycle for our vehicle, constant
velocity for the other) and, if the look-ahead breaks a SPEC §2 limit, replaces the command by a
hover. A hovering vehicle cannot cause a separation loss or a geofence exit; the worst outcome is
a timeout, which is the failure SPEC §2 calls safe.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uav_model.plant.unicycle import body_rollouts
from uav_model.world import World


@dataclass(frozen=True, slots=True)
class Kinematic2D:
    """Planar state for a look-ahead, ENU metres / radians."""

    x_m: float
    y_m: float
    heading_rad: float
    vx_m_s: float = 0.0
    vy_m_s: float = 0.0


@dataclass(frozen=True, slots=True)
class Verdict:
    hover: bool
    reason: str = ""  # "", "separation", "geofence", "stale"


FLY = Verdict(False)


def unicycle_points(start: Kinematic2D, forward_m_s: float, yaw_rate_rad_s: float,
                    horizon_s: float, step_s: float) -> np.ndarray:
    """(N, 2) positions of a constant (v, omega) command, the planner's own rollout model (the one
    unicycle integration, uav_model.plant.unicycle.body_rollouts, turned to the start heading)."""
    n = max(1, int(math.ceil(horizon_s / step_s)))
    body, _ = body_rollouts(forward_m_s, np.array([yaw_rate_rad_s]), step_s, n)
    bx, by = body[0, 1:, 0], body[0, 1:, 1]
    c, s = math.cos(start.heading_rad), math.sin(start.heading_rad)
    return np.column_stack([start.x_m + c * bx - s * by, start.y_m + s * bx + c * by])


def constant_velocity_points(start: Kinematic2D, horizon_s: float, step_s: float) -> np.ndarray:
    n = max(1, int(math.ceil(horizon_s / step_s)))
    t = step_s * np.arange(1, n + 1)
    return np.column_stack([start.x_m + start.vx_m_s * t, start.y_m + start.vy_m_s * t])


def predicted_min_separation_m(own: Kinematic2D, forward_m_s: float, yaw_rate_rad_s: float,
                               other: Kinematic2D, horizon_s: float, step_s: float,
                               other_moves: bool = True) -> float:
    """Closest approach over the look-ahead (now excluded: the caller compares against it)."""
    mine = unicycle_points(own, forward_m_s, yaw_rate_rad_s, horizon_s, step_s)
    if other_moves:
        theirs = constant_velocity_points(other, horizon_s, step_s)
    else:
        theirs = np.repeat([[other.x_m, other.y_m]], len(mine), axis=0)
    return float(np.min(np.hypot(*(mine - theirs).T)))


def check_separation(own: Kinematic2D, forward_m_s: float, yaw_rate_rad_s: float,
                     other: Kinematic2D | None, *, min_separation_m: float, own_has_priority: bool,
                     horizon_s: float, step_s: float, stop_m: float = 0.0) -> Verdict:
    """Hover if the look-ahead loses separation, plus ``stop_m`` (what this vehicle still flies
    once the hover is sent: :func:`stop_distance_m`).

    The lower-priority vehicle yields as soon as the constant-velocity prediction of the other
    breaks the limit. The priority vehicle keeps flying unless its own command would bring it
    within the limit of where the other vehicle is now (e.g. the other is already hovering).
    """
    if other is None:
        return FLY
    # Never closer than the limit; or, already inside it (a failsafe or a late sample brought them
    # there), never closer than now: else two hovering vehicles veto each other for ever.
    floor = min(min_separation_m + stop_m, math.hypot(own.x_m - other.x_m, own.y_m - other.y_m))
    moving = predicted_min_separation_m(own, forward_m_s, yaw_rate_rad_s, other, horizon_s, step_s, True)
    if moving >= floor:
        return FLY
    if not own_has_priority:
        return Verdict(True, "separation")
    still = predicted_min_separation_m(own, forward_m_s, yaw_rate_rad_s, other, horizon_s, step_s, False)
    return FLY if still >= floor else Verdict(True, "separation")


def check_geofence(world: World, own: Kinematic2D, forward_m_s: float, yaw_rate_rad_s: float, *,
                   horizon_s: float, step_s: float, stop_m: float = 0.0) -> Verdict:
    """Hover if the commanded arc would come within ``stop_m`` of the geofence within the
    look-ahead: the distance the vehicle still flies once the veto is sent (see :func:`stop_distance_m`).
    A vehicle already in that band, or outside (an autopilot mode flew it there), may fly any arc
    that never takes it further out: it must be able to come back, and every such arc begins out."""
    pts = np.vstack([[own.x_m, own.y_m], unicycle_points(own, forward_m_s, yaw_rate_rad_s, horizon_s, step_s)])
    m = world.geofence_margin_m - stop_m
    out_x = np.maximum.reduce([world.x_min_m - m - pts[:, 0], pts[:, 0] - world.x_max_m - m, np.zeros(len(pts))])
    out_y = np.maximum.reduce([world.y_min_m - m - pts[:, 1], pts[:, 1] - world.y_max_m - m, np.zeros(len(pts))])
    outside = np.hypot(out_x, out_y)  # how far beyond the band's inner edge, 0 inside
    return FLY if bool(np.all(np.diff(outside) <= 1e-9)) else Verdict(True, "geofence")


def stop_distance_m(speed_m_s: float, max_accel_m_s2: float, latency_s: float) -> float:
    """How far a vehicle flies after a hover is decided: what it flies on the old command until
    the new one acts (``latency_s`` sim: the pose's age plus a planner step), then its braking."""
    return speed_m_s * latency_s + speed_m_s ** 2 / (2.0 * max_accel_m_s2)


def is_stale(pose_t_sim_s: float, clock_t_sim_s: float | None, timeout_s: float) -> bool:
    """A pose is stale when the vehicle's own clock has moved on by more than the timeout."""
    return clock_t_sim_s is not None and clock_t_sim_s - pose_t_sim_s > timeout_s


def wall_bound_s(sim_timeout_s: float, sim_rate: float | None, *, floor_s: float = 0.1,
                 ceiling_s: float = 5.0) -> float:
    """How long (wall) to wait for fresh telemetry: the sim timeout at the measured speed factor.

    The floor keeps event-loop jitter from tripping it at high speed factors; the ceiling bounds
    the wait when the speed factor is still unknown.
    """
    if sim_rate is None or not math.isfinite(sim_rate) or sim_rate <= 0:
        return ceiling_s
    return min(ceiling_s, max(floor_s, sim_timeout_s / sim_rate))
