"""Rollout shapes: the body-frame rollouts computed once per config, and their placement at a
pose (one matrix product per tick)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from companion.planning.dwa.config import DwaConfig
    from companion.planning.dwa.types import Pose


def homogeneous(xy: np.ndarray) -> np.ndarray:
    """(N, 2) points as (3, N) homogeneous columns."""
    return np.ascontiguousarray(np.vstack([xy.T, np.ones(len(xy))]))


def placement(pose: Pose) -> np.ndarray:
    """(2, 3): left-multiplying homogeneous body points by this turns them to the pose's heading
    and moves them to its position."""
    c, s = math.cos(pose.heading_rad), math.sin(pose.heading_rad)
    place = np.empty((2, 3))  # filled in place: twice as fast as np.array of nested lists (every tick)
    place[0, 0], place[0, 1], place[0, 2] = c, -s, pose.x_m
    place[1, 0], place[1, 1], place[1, 2] = s, c, pose.y_m
    return place


def recovery_shapes(body: np.ndarray, final_dheading: np.ndarray, t: np.ndarray, max_yaw_rate: float,
                     dt: float, samples: int) -> dict[str, np.ndarray]:
    """The spin recovery's fixed shapes: a subset of the rollouts (the straight one included),
    turned by every heading a full-rate yaw reaches in whole ticks, up to half a turn each way
    (at most 72 headings: a slow-turning vehicle gets coarser steps)."""
    if samples <= 0 or max_yaw_rate <= 0:
        return {"rec_body_xy_m": np.zeros((0,) + body.shape[1:]), "rec_turn_rad": np.zeros(0),
                "rec_delay_s": np.zeros(0), "rec_final_dheading_rad": np.zeros(0), "rec_point_times_s": np.zeros(0)}
    idx = np.unique(np.round(np.linspace(0, len(body) - 1, min(samples, len(body)))).astype(int))
    idx = np.union1d(idx, [len(body) // 2])
    step = max(max_yaw_rate * dt, math.pi / 36)
    n = math.ceil(math.pi / step - 1e-9)
    j = np.concatenate([-np.arange(n, 0, -1), np.arange(1, n + 1)])
    j = j[np.abs(j * step) <= math.pi + 1e-9]
    turn = j * step
    delay = np.ceil(np.abs(turn) / (max_yaw_rate * dt) - 1e-9) * dt
    c, s = np.cos(turn)[:, None, None], np.sin(turn)[:, None, None]
    bx, by = body[idx, :, 0][None], body[idx, :, 1][None]
    shapes = np.stack([c * bx - s * by, s * bx + c * by], axis=-1).reshape(-1, body.shape[1], 2)
    turn_r = np.repeat(turn, len(idx))
    delay_r = np.repeat(delay, len(idx))
    return {"rec_body_xy_m": shapes, "rec_turn_rad": turn_r, "rec_delay_s": delay_r,
            "rec_final_dheading_rad": turn_r + np.tile(final_dheading[idx], len(j)),
            "rec_point_times_s": (np.tile(t, len(turn_r)).reshape(len(turn_r), -1) + delay_r[:, None]).ravel()}



def lagged_rollouts(speeds_m_s: np.ndarray, rates_rad_s: np.ndarray, cruise_m_s: float, dt_s: float, steps: int,
                    lag_s: float, substeps: int = 20) -> np.ndarray:
    """The rollouts (S, K + 1, 2) as a plant whose velocity trails its command by a first-order
    lag of ``lag_s`` flies them, from cruise along the heading (body frame): the heading turns
    at the rollout's yaw rate, the velocity relaxes toward the rollout's speed along it. The
    multicopter flies its commands within 2-4 m of these over an 11 s horizon with a 2 s lag,
    where it strays up to 17 m from the unicycle's arcs (it flies wide of every turn)."""
    h = dt_s / substeps
    keep = 1.0 - math.exp(-h / lag_s)
    vx, vy = np.full(len(rates_rad_s), float(cruise_m_s)), np.zeros(len(rates_rad_s))
    x, y = np.zeros(len(rates_rad_s)), np.zeros(len(rates_rad_s))
    out = np.zeros((len(rates_rad_s), steps + 1, 2))
    for k in range(steps * substeps):
        heading = rates_rad_s * ((k + 0.5) * h)
        vx += (speeds_m_s * np.cos(heading) - vx) * keep
        vy += (speeds_m_s * np.sin(heading) - vy) * keep
        x += vx * h
        y += vy * h
        if (k + 1) % substeps == 0:
            out[:, (k + 1) // substeps, 0], out[:, (k + 1) // substeps, 1] = x, y
    return out


def lagged_points(pose: Pose, config: DwaConfig) -> np.ndarray | None:
    """(2, S * (K + 1)): the rollouts' points as the lagging plant flies them from the pose's
    velocity (:meth:`.Pose.velocity_m_s`); None when the plant flies the rollouts exactly."""
    if config.lagged_rest_hom_m is None:
        return None
    xy = placement(pose) @ config.lagged_rest_hom_m
    vx, vy = pose.velocity_m_s(config.speed_m_s)
    xy[0] += vx * config.lagged_drift_s
    xy[1] += vy * config.lagged_drift_s
    return xy


def rollouts(pose: Pose, config: DwaConfig) -> tuple[np.ndarray, np.ndarray]:
    """All rollouts for ``pose``: points (S, K + 1, 2) at config.times_s (the first is the pose
    itself) and the headings (S,) at the prediction point."""
    xy = placement(pose) @ config.body_hom_m  # (2, N)
    return np.stack([xy[0], xy[1]], axis=-1).reshape(config.body_xy_m.shape), pose.heading_rad + config.final_dheading_rad



def rotation(heading_rad: float) -> np.ndarray:
    """Right-multiplying (N, 2) body points by this turns them to ``heading_rad``."""
    c, s = math.cos(heading_rad), math.sin(heading_rad)
    return np.array([[c, s], [-s, c]])
