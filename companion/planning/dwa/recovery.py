"""What a vehicle does when every rollout at cruise speed breaks a rule: recover, hold or escape.

In this order (:func:`no_legal_rollout`):

1. Spin recovery (nav2's spin behaviour; a multicopter can yaw in place): the rollouts that
   start here after a yaw in place to another heading, under the same rules and critics,
   with moving obstacles and the other UAVs predicted over the yaw time too and the hover
   point safe while yawing. The best one's heading is the target: yaw toward it, speed 0.
   Without this a vehicle in a pocket hovers with a fixed heading for ever.
2. Hold, if the hover point stays clear of the inflated obstacles (moving ones predicted at
   constant velocity) and of every other UAV for a full spin plus a horizon.
3. The hover point is going to be hit: the recovery judged on the TRUE footprints (the
   inflation margin is the reserve an emergency may use); else
4. the rollout from the current heading that stays clear of the true footprints longest,
   if it lasts longer than hovering (the escape); else hold. A plant that lags is judged on
   the rollout and on its flight of it (:func:`.shapes.lagged_rollouts`): it flies wide of a
   turn, by up to 17 m for the multicopter, and an escape that grazes a true footprint on the
   rollout is flown into it.

A plant that lags its commands (``config.tracking_lag_s`` > 0, the multicopter) does not stop
where it is, nor get going at once after a yaw: the hover is judged on its braking segment,
until the lag after the spin (:func:`hover_check`), and when that stopping point is going to
be hit, a rollout at speed that stays clear of the true footprints for the whole horizon is
flown before step 3 (stopping, yawing and accelerating again in a moving obstacle's path is
what the recovery cannot promise on such a plant).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np

from companion.planning.dwa.evaluate import command_for, evaluate
from companion.planning.dwa.geometry import inflated_clearance
from companion.planning.dwa.legality import (Rule, fence_distance, inside_fence_by, separation_limits2,
                                             uav_distance2, within_separation_reach)
from companion.planning.dwa.shapes import rotation
from companion.planning.dwa.sightline import sightline_term
from companion.planning.dwa.snapshot import ObstacleSnapshot
from companion.planning.dwa.types import Command, LocalGoals, NoLegalRollout, OtherUav, Pose

if TYPE_CHECKING:
    from companion.planning.dwa.config import DwaConfig


@dataclass(frozen=True, eq=False)
class HoverCheck:
    """Whether hovering here stays clear, step by step over a spin plus a horizon."""

    steps: int
    inflated: np.ndarray  # (steps + 1,) clear of the inflated obstacles and the other UAVs up to step k
    true: np.ndarray  # (steps + 1,) the same on the true footprints
    field: ObstacleSnapshot  # the obstacles within reach over that time
    margins: np.ndarray | None  # (O, 1) inflation margins of ``field``
    floor_inflated: np.ndarray | None  # (O, 1) how deep the pose is in each inflated obstacle now (<= 0)
    floor_true: np.ndarray | None
    sep_from: tuple[OtherUav, ...]  # the UAVs kept separated from, those within reach (separation_reach)
    sep_limit2: np.ndarray | None  # (N, 1, 1) the squared separation kept from each, when any
    sep_bare2: np.ndarray | None  # the same without the right of way's margin (on the true footprints)


@dataclass(frozen=True, eq=False)
class Stuck:
    """What the tick that found no legal rollout hands the recovery: each rule's mask per
    rollout point (S, K + 1), and how to work out the heading critic (S,), the obstacles within
    reach and the rollouts' clearances to them (O, S * (K + 1)): only the escape reads those, so
    a vehicle that holds or recovers never pays for them."""

    ok_by_rule: dict[Rule, np.ndarray]
    heading_critic: Callable[[], np.ndarray]
    near_obstacles: Callable[[], ObstacleSnapshot]
    clearances: Callable[[], np.ndarray | None]
    lagged_clearances: Callable[[], np.ndarray | None] = lambda: None  # the same, as a lagging plant flies them
    # The separation rule (S, K + 1) without the right of way's margin, on the rollouts and as a
    # lagging plant flies them (None: no UAV can bind).
    bare_separation: Callable[[], np.ndarray | None] = lambda: None

    @cached_property
    def heading(self) -> np.ndarray:
        return self.heading_critic()

    @cached_property
    def near(self) -> ObstacleSnapshot:
        return self.near_obstacles()

    @cached_property
    def clear(self) -> np.ndarray | None:
        return self.clearances()

    @cached_property
    def lagged(self) -> np.ndarray | None:
        return self.lagged_clearances()

    @cached_property
    def separation(self) -> np.ndarray | None:
        return self.bare_separation()


def no_legal_rollout(pose: Pose, goals: LocalGoals, other: OtherUav | None, snapshot: ObstacleSnapshot,
                     config: DwaConfig, stuck: Stuck,
                     separate_from: Sequence[OtherUav] | None = None) -> NoLegalRollout:
    """The four strategies of the module docstring, in order. ``other``: the sightline partner;
    ``separate_from``: every UAV kept separated from (None: ``other`` alone)."""
    blocking = [rule for rule, ok in stuck.ok_by_rule.items() if not ok[:, 1:].all(axis=1).any()]
    what = ", ".join(blocking) if blocking else "no rollout satisfies all rules at once"
    reason = f"all {config.count} rollouts break a rule within {config.prediction_time_s:g} s ({what})"
    if separate_from is None:
        separate_from = () if other is None else (other,)
    hover = hover_check(pose, separate_from, snapshot, config)
    if config.rec_delay_s.size:
        pts, ok_inf, ok_true, distance = spin_candidates(pose, config, hover)
        for legal, how in ((ok_inf, "recovering"), (None, None), (ok_true, "recovering on the margin")):
            if legal is None:  # between the two recoveries: a hover that stays clear is the better wait
                if hover.inflated[-1]:
                    return NoLegalRollout(f"{reason}; holding: no heading has a legal rollout")
                if config.tracking_lag_s > 0.0 and not hover.true[-1]:
                    # Stopping here will be hit: a lagging plant flies on rather than stop, yaw and restart.
                    flying = escape(config, stuck, hover, reason, whole_horizon=True)
                    if flying is not None:
                        return flying
                continue
            if legal.any():
                return spin_recovery(pose, goals, other, snapshot, config, pts, legal, distance, f"{reason}; {how}")
    elif hover.inflated[-1]:
        return NoLegalRollout(reason)
    return escape(config, stuck, hover, reason)


def hover_check(pose: Pose, separate_from: Sequence[OtherUav], snapshot: ObstacleSnapshot,
                config: DwaConfig) -> HoverCheck:
    """The hover point over a spin plus a horizon, inflated and true, against the obstacles and
    every UAV of ``separate_from``: the true check keeps the bare separation (without the right
    of way's margin, :func:`.legality.kept_from`), never less.

    A plant that lags (``config.tracking_lag_s``) does not hover where it is: the multicopter
    commanded to hover at cruise carries on ~18 m along its velocity (:func:`braking_segment`),
    and gets going again that lag after its yaw. The obstacles and the other UAVs are judged on
    the whole braking segment (the worst point of it at every time) and over the spin plus the lag plus a horizon,
    so that a recovery never parks the vehicle in the path of a moving obstacle that only misses
    the pose (a shuttling disc that reverses while the braking vehicle ends up inside its path
    and yaws there is otherwise a collision)."""
    dt = config.dt_s
    hover_steps = config.steps + round((config.spin_time_s + config.tracking_lag_s) / dt)
    t_hover = dt * np.arange(hover_steps + 1)
    field_h = config.backend.near(snapshot, pose.x_m, pose.y_m, config.reach_m + config.distance_saturation_m,
                                  float(t_hover[-1]))
    margins = np.concatenate([field_h.circle_margin_m, field_h.poly_margin_m])[:, None]
    hover_inf = np.ones(hover_steps + 1, dtype=bool)
    hover_true = hover_inf.copy()
    floor_inf = floor_true = None
    if field_h.count:
        # Only the obstacles that can come within 1 m of the braking segment are measured: the
        # others stay clear of it, so their floors are 0 and they never bind.
        close = config.backend.cull(field_h, pose.x_m, pose.y_m, config.stop_drift_m + 1.0, float(t_hover[-1]))
        floor_inf, floor_true = np.zeros((field_h.count, 1)), np.zeros((field_h.count, 1))
    sep_from = within_separation_reach(pose, separate_from, config) if config.min_separation_m > 0 else ()
    if (floor_inf is not None and close.count) or sep_from:  # else hovering is clear of everything
        bx, by = braking_segment(pose, config)
    if floor_inf is not None and close.count:
        floor_inf[close.keep], floor_true[close.keep], clear_inf, clear_true = config.backend.braking_checks(
            bx, by, t_hover, close.subset())
        hover_inf &= clear_inf
        hover_true &= clear_true
    sep_limit2 = sep_bare2 = None
    if sep_from:
        sep_limit2 = separation_limits2(pose, sep_from, config).reshape(-1, 1, 1)
        sep_bare2 = separation_limits2(pose, sep_from, config, courtesy=False).reshape(-1, 1, 1)
        # On the braking segment too (the worst point of it at each time), as for the obstacles:
        # a vehicle stopping 20 m short of another that it keeps clear of by 5 m is too close.
        d2 = uav_distance2(bx[:, None], by[:, None], t_hover, sep_from)  # (N, braking points, steps + 1)
        d2 = np.concatenate([d2[:, 0, 0:1], d2[:, :, 1:].min(axis=1)], axis=1)  # the pose itself now
        hover_inf &= (d2 >= sep_limit2[:, 0]).all(axis=0)
        hover_true &= (d2 >= sep_bare2[:, 0]).all(axis=0)
    return HoverCheck(hover_steps, np.logical_and.accumulate(hover_inf), np.logical_and.accumulate(hover_true),
                      field_h, margins, floor_inf, floor_true, sep_from, sep_limit2, sep_bare2)


def braking_segment(pose: Pose, config: DwaConfig) -> tuple[np.ndarray, np.ndarray]:
    """Points (x, y) every 2 m or less along where the plant carries on when commanded to hover:
    its lag times its velocity (:meth:`.Pose.velocity_m_s`) from the pose; the pose alone
    when it does not lag, or stands still."""
    vx, vy = pose.velocity_m_s(config.speed_m_s)
    drift = config.tracking_lag_s * math.hypot(vx, vy)
    ahead = np.linspace(0.0, 1.0, 1 + math.ceil(drift / _DRIFT_STEP_M))
    return pose.x_m + ahead * (config.tracking_lag_s * vx), pose.y_m + ahead * (config.tracking_lag_s * vy)


def braking_checks(bx: np.ndarray, by: np.ndarray, t_s: np.ndarray,
                   snap: ObstacleSnapshot) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The obstacles of ``snap`` against the braking segment (bx, by) over the times t_s (T,):
    how deep its first point is in each inflated and each true obstacle at t_s[0] (<= 0; (O, 1)
    each), and at each time whether the segment's worst point is no deeper in any ((T,) each)."""
    hc = inflated_clearance(np.repeat(bx, len(t_s)), np.repeat(by, len(t_s)), np.tile(t_s, len(bx)), snap)
    if len(bx) > 1:  # the worst point of the braking segment at each time; the floor is the pose's
        hc = np.concatenate([hc[:, 0:1], hc.reshape(len(hc), len(bx), -1).min(axis=1)[:, 1:]], axis=1)
    margins = np.concatenate([snap.circle_margin_m, snap.poly_margin_m])[:, None]
    floor_inf, floor_true = np.minimum(hc[:, 0:1], 0.0), np.minimum(hc[:, 0:1] + margins, 0.0)
    return (floor_inf, floor_true, (hc >= floor_inf - 1e-9).all(axis=0),
            (hc + margins >= floor_true - 1e-9).all(axis=0))


# Spacing of the points a braking segment is judged on (m): far below any obstacle's size.
_DRIFT_STEP_M = 2.0


def spin_candidates(pose: Pose, config: DwaConfig, hover: HoverCheck) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The recovery rollouts placed at the pose (R, K + 1, 2), which of them are legal on the
    inflated and on the true footprints (R,) each, and their distance critic (R,)."""
    body = config.rec_body_xy_m
    pts = (body.reshape(-1, 2) @ rotation(pose.heading_rad)).reshape(body.shape)
    pts.view(np.complex128)[...] += complex(pose.x_m, pose.y_m)  # x + x_m, y + y_m: a (2,) broadcast is slower
    px, py = pts[..., 0], pts[..., 1]
    n_r = len(pts)
    delay_k = np.rint((config.rec_delay_s + config.tracking_lag_s) / config.dt_s).astype(int)  # hovers until going
    ok_inf, ok_true = hover.inflated[delay_k], hover.true[delay_k]
    here = fence_distance(pose, config)  # each rule only where it can bind, as on the tick's rollouts
    if here is not None:
        inside = (inside_fence_by(px, py, config.fence_m) >= min(here, 0.0) - 1e-9)[:, 1:].all(axis=1)
        ok_inf, ok_true = ok_inf & inside, ok_true & inside
    if hover.sep_limit2 is not None:  # (N, R, K) at once; on the true footprints, the bare separation
        t = config.rec_point_times_s.reshape(n_r, -1)
        ox, oy, ovx, ovy = np.array([(o.x_m, o.y_m, o.vx_m_s, o.vy_m_s) for o in hover.sep_from]).T[:, :, None, None]
        d2 = ((px - ox - ovx * t) ** 2 + (py - oy - ovy * t) ** 2)[..., 1:]
        ok_inf = ok_inf & (d2 >= hover.sep_limit2).all(axis=(0, 2))
        ok_true = ok_true & (d2 >= hover.sep_bare2).all(axis=(0, 2))
    if not hover.field.count:
        return pts, ok_inf, ok_true, np.full(n_r, config.distance_saturation_m)
    return (pts, *config.backend.spin_checks(pts, config, hover, ok_inf, ok_true))


def spin_checks(pts: np.ndarray, config: DwaConfig, hover: HoverCheck, ok_inf: np.ndarray,
                ok_true: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The obstacle rule on the recovery rollouts ``pts`` (R, K + 1, 2) against ``hover.field``:
    ``ok_inf`` and ``ok_true`` (R,), which may still be legal on the inflated and on the true
    footprints, narrowed to those that are, and the distance critic (R,), meaningful where
    either is legal.

    Point by point along the rollouts, over the ones still legal on either footprint only, and
    against the obstacles that can come near those points (a point farther from an obstacle's
    bounding disc than the saturation plus 1 m can neither break the rule nor set the critic):
    when the vehicle is boxed in (every rollout breaks the rule a few points out) this stops
    after a few points instead of measuring every point of every heading to every obstacle."""
    px, py = pts[..., 0], pts[..., 1]
    field, times = hover.field, config.rec_point_times_s.reshape(px.shape)
    limits = np.stack([hover.floor_inflated[:, 0], hover.floor_true[:, 0], hover.margins[:, 0]])  # (3, O)
    beyond = max(config.distance_saturation_m, 0.0) + 1.0
    ok_inf, ok_true = ok_inf.copy(), ok_true.copy()
    lowest = np.full(len(px), np.inf)
    alive = np.flatnonzero(ok_inf | ok_true)
    for k in range(1, px.shape[1]):
        if not len(alive):
            break
        x, y, t = px[alive, k], py[alive, k], times[alive, k]
        # the obstacles whose bounding disc, moving at its speed, comes near the points' box
        bx, by = field.bound_xy_m[:, 0], field.bound_xy_m[:, 1]
        dx = np.maximum(np.maximum(x.min() - bx, bx - x.max()), 0.0)
        dy = np.maximum(np.maximum(y.min() - by, by - y.max()), 0.0)
        keep = np.hypot(dx, dy) <= field.bound_radius_m + field.speed_m_s * t.max() + beyond
        count = int(np.count_nonzero(keep))
        if not count:
            continue
        rc = inflated_clearance(x, y, t, field.subset(keep, count))  # (O', A)
        floor_inf, floor_true, margins = limits[:, keep, None]
        ok_inf[alive] &= (rc >= floor_inf - 1e-9).all(axis=0)
        ok_true[alive] &= (rc + margins >= floor_true - 1e-9).all(axis=0)
        lowest[alive] = np.minimum(lowest[alive], rc.min(axis=0))
        alive = alive[ok_inf[alive] | ok_true[alive]]
    return ok_inf, ok_true, np.clip(lowest, 0.0, config.distance_saturation_m)


def spin_recovery(pose: Pose, goals: LocalGoals, other: OtherUav | None, snapshot: ObstacleSnapshot,
                  config: DwaConfig, pts: np.ndarray, legal: np.ndarray, distance: np.ndarray,
                  reason: str) -> NoLegalRollout:
    """Yaw in place (speed 0) toward the best legal recovery rollout's heading."""
    # the heading critic of the legal ones only: the others' never counts
    scores = config.backend.heading_scores(pts, pose.heading_rad + config.rec_final_dheading_rad, goals,
                                           np.flatnonzero(legal))
    sight = sightline_term(pose, other, snapshot, config, pts[:, -1, 0], pts[:, -1, 1])
    total = evaluate(config, legal, scores, distance, sight)
    i = int(total.argmax())
    turn = float(config.rec_turn_rad[i])
    yaw_rate = max(-config.max_yaw_rate_rad_s, min(config.max_yaw_rate_rad_s, turn / config.dt_s))
    command = Command(yaw_rate_rad_s=yaw_rate, speed_m_s=0.0, heading_score=float(scores[i]),
                      distance_score=float(distance[i]),
                      sightline_score=0.0 if sight is None else float(sight[i]),
                      eval_score=float(total[i]), legal_count=int(np.count_nonzero(legal)))
    return NoLegalRollout(f"{reason}: yaw {math.degrees(turn):+.0f} deg in place", recovery=command, turn_rad=turn)


def escape(config: DwaConfig, stuck: Stuck, hover: HoverCheck, reason: str,
           whole_horizon: bool = False) -> NoLegalRollout | None:
    """Hovering will be hit and no heading helps: fly what stays clear of the true footprints
    longest (of those, the one keeping the most clearance), if that outlasts hovering; else hold.
    ``whole_horizon``: only a rollout clear of them for the whole horizon, else None."""
    dt, steps, hover_steps = config.dt_s, config.steps, hover.steps
    ok_by_rule, heading, near, clear = stuck.ok_by_rule, stuck.heading, stuck.near, stuck.clear
    ok_pts = np.ones((config.count, steps + 1), dtype=bool)
    for rule, ok in ok_by_rule.items():
        if rule is Rule.SEPARATION and stuck.separation is not None:
            ok_pts &= stuck.separation  # the right of way's margin is a reserve, as the inflation is
        elif rule is not Rule.OBSTACLE:
            ok_pts &= ok
    kept = None  # (S,) the least true clearance each rollout keeps over the horizon
    if clear is not None:
        margins = np.concatenate([near.circle_margin_m, near.poly_margin_m])
        true_clear = clear + margins[:, None]
        if stuck.lagged is not None:  # the plant flies wide of a turn: clear on the rollout and as flown
            true_clear = np.minimum(true_clear, stuck.lagged + margins[:, None])
        ok_pts &= (true_clear >= np.minimum(true_clear[:, 0:1], 0.0) - 1e-9).all(axis=0).reshape(ok_pts.shape)
        if len(margins):
            kept = true_clear.min(axis=0).reshape(ok_pts.shape)[:, 1:].min(axis=1)
    # legal steps flown; a rollout clear for the whole horizon outlasts any hover
    lasts = np.where(ok_pts[:, 1:].all(axis=1), hover_steps + 1, np.argmin(ok_pts[:, 1:], axis=1))
    if whole_horizon:  # flying on: a hover rollout would stop after all
        lasts = np.where(config.speeds_m_s > 0.0, lasts, 0)
    hold_lasts = hover_steps if hover.true[-1] else int(np.argmin(hover.true[1:]))
    best_last = int(lasts.max())
    if whole_horizon and best_last <= hover_steps:
        return None
    if best_last <= hold_lasts:
        return NoLegalRollout(f"{reason}; holding: nothing lasts longer than hovering ({hold_lasts * dt:g} s)")
    longest = lasts == best_last
    if kept is not None:
        # Of those, the one that keeps the most true clearance (the heading breaks ties). The
        # plant lags its commands, so a rollout that grazes a true footprint is a collision, and
        # an escape repeated tick after tick that trades clearance for heading ratchets into an
        # obstacle (escaping a shuttle, each tick a few metres closer to a static disc than the
        # clearest rollout, until the lagging plant hits the disc).
        longest = longest & (kept >= kept[longest].max() - 1e-9)
    i = int(np.argmax(np.where(longest, heading, -np.inf)))
    command = command_for(config, i, heading, np.zeros(config.count), None, 0.0, 0)
    clear_for = "the horizon" if best_last > hover_steps else f"{min(best_last, steps) * dt:g} s"
    return NoLegalRollout(f"{reason}; escaping: clear for {clear_for}, hovering for {hold_lasts * dt:g} s", command)
