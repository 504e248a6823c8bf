"""Legality: the rules that discard a rollout instead of scoring it (nav2 DWB reports illegal
trajectories with a reason; here each rule keeps its own mask so that the reason can be named).

- obstacle: no rollout point inside an inflated obstacle. A vehicle already inside one (a moving
  obstacle came to it) may only fly rollouts that never get deeper than it is now;
- separation: no rollout point closer than ``min_separation_m`` to any other UAV predicted at
  constant velocity (same relaxation, per UAV, when already closer). Every UAV whose predicted
  path can come within reach counts, all of them in one array operation (rollouts x UAVs x
  steps): with more than two vehicles, keeping clear of one at a time loses the separation
  where several routes meet;
- geofence: no rollout point outside the keep-in box (same relaxation when already outside).

The turn-around preference (:func:`commit_turn`) narrows the legal set but is never a rule.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from enum import Enum
from typing import TYPE_CHECKING

import numpy as np

from companion.planning.dwa.types import LocalGoals, OtherUav, Pose

if TYPE_CHECKING:
    from companion.planning.dwa.config import DwaConfig


class Rule(str, Enum):
    """A legality rule; the value is how a reason names it."""

    OBSTACLE = "obstacle"
    SEPARATION = "separation"
    GEOFENCE = "geofence"


def kept_from(other: OtherUav, config: DwaConfig, courtesy: bool = True) -> float:
    """The separation a rollout keeps from ``other``: more when it has right of way, unless
    ``courtesy`` is off (the bare separation: a vehicle with no legal rollout may use the right
    of way's margin, as it may use an obstacle's inflation)."""
    if other.right_of_way and courtesy:
        return config.min_separation_m + config.yield_margin_m
    return config.min_separation_m


def separation_can_bind(pose: Pose, other: OtherUav | None, config: DwaConfig) -> bool:
    """Whether the other UAV's predicted path comes within reach of any rollout."""
    return other is not None and config.min_separation_m > 0 and (
        math.hypot(pose.x_m - other.x_m, pose.y_m - other.y_m) <= config.reach_m + kept_from(other, config)
        + math.hypot(other.vx_m_s, other.vy_m_s) * config.horizon_s + 1.0)


def separation_reach(config: DwaConfig) -> tuple[float, float]:
    """(m, s): a UAV farther from the pose than the first plus its speed times the second can
    bind none of this config's rules, nor its recovery's or its hover's (the rollouts, lagged
    or not, reach no farther than cruise x horizon; a recovery starts at most a spin plus the
    lag later), so a caller may leave it out of ``separate_from``."""
    return (config.reach_m + config.stop_drift_m + config.min_separation_m + config.yield_margin_m + 1.0,
            config.horizon_s + config.spin_time_s + config.tracking_lag_s + config.dt_s)


def within_separation_reach(pose: Pose, others: Sequence[OtherUav], config: DwaConfig) -> tuple[OtherUav, ...]:
    """The UAVs of ``others`` within :func:`separation_reach` of the pose: the others can bind
    no rule of this config, nor its recovery's or its hover's."""
    metres, seconds = separation_reach(config)
    return tuple(o for o in others if math.hypot(pose.x_m - o.x_m, pose.y_m - o.y_m)
                 <= metres + math.hypot(o.vx_m_s, o.vy_m_s) * seconds)


def fence_distance(pose: Pose, config: DwaConfig) -> float | None:
    """The pose's distance inside the fence (negative outside), or None when no fence or no
    rollout can reach it."""
    fence = config.fence_m
    if fence is None:
        return None
    here = min(pose.x_m - fence[0], fence[2] - pose.x_m, pose.y_m - fence[1], fence[3] - pose.y_m)
    return here if here < config.reach_m else None


def obstacle_ok(clear: np.ndarray, lowest: np.ndarray) -> np.ndarray:
    """(N,) per rollout point, from the clearances (O, N) and their minimum over obstacles."""
    if clear[:, 0].min() >= 0.0:  # outside every inflated obstacle: no rollout point may enter one
        return lowest >= -1e-9
    return (clear >= np.minimum(clear[:, 0:1], 0.0) - 1e-9).all(axis=0)  # already inside: never deeper


def binding_uavs(pose: Pose, others: Sequence[OtherUav], config: DwaConfig) -> tuple[OtherUav, ...]:
    """The UAVs of ``others`` whose predicted path can come within the separation of a rollout."""
    if len(others) == 1:  # two vehicles flying: every tick, without a generator
        return tuple(others) if separation_can_bind(pose, others[0], config) else ()
    return tuple(o for o in others if separation_can_bind(pose, o, config))


def separation_limits2(pose: Pose, others: Sequence[OtherUav], config: DwaConfig,
                       courtesy: bool = True) -> np.ndarray:
    """(N,): the squared separation kept from each UAV (:func:`kept_from`), or the distance now
    when it is already closer (a rollout may then not get any closer); 1e-6 m of slack."""
    return np.array([(min(kept_from(o, config, courtesy), math.hypot(pose.x_m - o.x_m, pose.y_m - o.y_m)) - 1e-6)
                     ** 2 for o in others])


def uav_distance2(px: np.ndarray, py: np.ndarray, times: np.ndarray, others: Sequence[OtherUav]) -> np.ndarray:
    """(N, *px.shape): squared distance from the points (px, py) at ``times`` (broadcasting
    against px) to each UAV predicted at constant velocity."""
    state = np.array([(o.x_m, o.y_m, o.vx_m_s, o.vy_m_s) for o in others]).reshape((len(others),) + (1,) * px.ndim + (4,))
    ox = state[..., 0] + state[..., 2] * times
    oy = state[..., 1] + state[..., 3] * times
    return (px - ox) ** 2 + (py - oy) ** 2


def separation_ok(px: np.ndarray, py: np.ndarray, times: np.ndarray, pose: Pose, others: Sequence[OtherUav],
                  config: DwaConfig, courtesy: bool = True) -> np.ndarray:
    """(S, K + 1): rollout points far enough from every UAV of ``others`` predicted at constant
    velocity (``courtesy``: see :func:`kept_from`)."""
    ok = uav_distance2(px, py, times, others) >= separation_limits2(pose, others, config, courtesy).reshape(-1, 1, 1)
    return ok[0] if len(ok) == 1 else ok.all(axis=0)


def inside_fence_by(px: np.ndarray, py: np.ndarray, fence: tuple[float, float, float, float]) -> np.ndarray:
    """How far each point is inside the box (negative outside)."""
    return np.minimum(np.minimum(px - fence[0], fence[2] - px), np.minimum(py - fence[1], fence[3] - py))


def fence_ok(px: np.ndarray, py: np.ndarray, fence: tuple[float, float, float, float], here: float) -> np.ndarray:
    """(S, K + 1): rollout points inside the fence, or no further out than the pose is now.

    Outside, a rollout must also end further in than the pose: "no further out" alone lets a
    plant that trails its rollouts ratchet outward a little every tick along the fence."""
    depth = inside_fence_by(px, py, fence)
    ok = depth >= min(here, 0.0) - 1e-9
    if here < 0.0:
        ok &= depth[:, -1:] > here
    return ok


def legal_rollouts(ok_by_rule: dict[Rule, np.ndarray], config: DwaConfig) -> np.ndarray:
    """(S,): rollouts whose every point after the first obeys every rule."""
    ok_pts = None
    for ok in ok_by_rule.values():
        ok_pts = ok if ok_pts is None else ok_pts & ok
    return config.all_legal if ok_pts is None else ok_pts[:, 1:].all(axis=1)


def turn_error(pose: Pose, goals: LocalGoals, config: DwaConfig) -> float:
    """The goal's bearing off the nose (rad) when the turn-around preference applies, else NaN
    (see :func:`commit_turn`)."""
    gx, gy = goals.first_xy  # floats: numpy scalars would cost more than the arithmetic
    error = (math.atan2(gy - pose.y_m, gx - pose.x_m) - pose.heading_rad + math.pi) % (2.0 * math.pi) - math.pi
    return math.nan if abs(error) <= math.radians(config.turnaround_deg) else error


def commit_turn(legal: np.ndarray, config: DwaConfig, error: float) -> np.ndarray:
    """Turn-around rule: with the goal more than ``turnaround_deg`` off the nose (``error``, from
    :func:`turn_error`; NaN: it is not), only turns toward the goal's side (or straight on) stay
    candidates.

    With p long enough for a U-turn (the paper's formula), a goal behind the vehicle is matched
    at the prediction point equally well by turning left or right. Which side wins then flips
    with sample quantisation from one tick to the next, and the vehicle chatters between the
    two U-turns while flying away from its goal (nav2 DWB's OscillationCritic exists for the
    same reason). The side of the goal as seen from the current pose is a stable choice: turning
    toward it only shrinks the angle. It is a preference, not a safety rule: if it would leave
    no legal rollout, it is dropped.
    """
    if math.isnan(error):
        return legal
    toward = legal & (config.yaw_rates_rad_s * error >= 0.0)
    return toward if toward.any() else legal
