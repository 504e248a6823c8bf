"""plan_step: one BDWA decision, wiring rollouts, legality, critics and evaluation together."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from companion.planning.dwa import kernels
from companion.planning.dwa.config import DwaConfig
from companion.planning.dwa.distance import no_obstacle_in_reach, obstacle_and_distance
from companion.planning.dwa.evaluate import choose, command_for, pick
from companion.planning.dwa.geometry import inflated_clearance, one_layout
from companion.planning.dwa.heading import heading_from_ends, single_target
from companion.planning.dwa.legality import (Rule, binding_uavs, fence_distance, fence_ok, legal_rollouts,
                                             separation_ok, turn_error)
from companion.planning.dwa.recovery import no_legal_rollout
from companion.planning.dwa.shapes import placement
from companion.planning.dwa.sightline import sightline_scores, sightline_term
from companion.planning.dwa.snapshot import ObstacleSnapshot, with_turned_back
from companion.planning.dwa.speed import reference_speed_m_s, speed_scores
from companion.planning.dwa.types import Command, LocalGoals, NoLegalRollout, OtherUav, Pose


def plan_step(pose: Pose, goals: LocalGoals | tuple[float, float], other: OtherUav | None,
              snapshot: ObstacleSnapshot, config: DwaConfig,
              scheduled_speed_m_s: float | None = None,
              separate_from: Sequence[OtherUav] | None = None) -> Command | NoLegalRollout:
    """One BDWA decision: the best legal yaw rate (and speed, with a speed window) toward the
    local goal, or NoLegalRollout. ``scheduled_speed_m_s``: what a timed route asks for now
    (the speed critic's reference; None: cruise). ``other`` is the UAV the sightline term hides
    from; ``separate_from`` every UAV the separation rule keeps clear of (None: ``other`` alone).

    ``goals`` is a :class:`LocalGoals` window (what the vehicle planner passes) or a bare (x, y).
    Every array here is small (31 x 23 points), so the cost is the number of numpy calls, not
    arithmetic: the whole rollouts are placed only when a rule or the goal window reads them
    (in open air only the 31 prediction points are), and each rule is skipped when it cannot bind.
    """
    if not isinstance(goals, LocalGoals):
        goals = LocalGoals.single(goals)
    if config.count > config.samples:  # a speed window: keep clear of receding obstacles turning back too
        cautious = with_turned_back(snapshot, pose.x_m, pose.y_m)
        if cautious is not snapshot:
            found = _step(pose, goals, other, cautious, snapshot, config, scheduled_speed_m_s, separate_from,
                          cautious=True)
            if found is not None:
                return found
    return _step(pose, goals, other, snapshot, snapshot, config, scheduled_speed_m_s, separate_from)


def _step(pose: Pose, goals: LocalGoals, other: OtherUav | None, snapshot: ObstacleSnapshot,
          sighted: ObstacleSnapshot, config: DwaConfig, scheduled_speed_m_s: float | None,
          separate_from: Sequence[OtherUav] | None, cautious: bool = False) -> Command | NoLegalRollout | None:
    """:func:`plan_step` against ``snapshot``; the sightline term reads ``sighted`` (where the
    obstacles are predicted to be). ``cautious``: ``snapshot`` also has the receding obstacles
    turned back, a precaution only: when it leaves no legal move, None (the caller plans without
    it) rather than an escape from obstacles that are not coming, which can take the vehicle
    into a static one."""
    shape = (config.count, config.steps + 1)
    reach = config.reach_m + config.distance_saturation_m
    if kernels.obstacle_pass is not None and config.row_of is None:
        # Compiled, the obstacle pass reads the snapshot through the culling mask: the culled
        # subset (a new one each tick when a moving obstacle is in it) is built only if read.
        keep, n_near = snapshot.near_mask(pose.x_m, pose.y_m, reach, config.horizon_s)
        near = None
    else:
        near = snapshot.near(pose.x_m, pose.y_m, reach, config.horizon_s)
        keep, n_near = None, near.count
    if separate_from is None:
        separate_from = () if other is None else (other,)
    binding = binding_uavs(pose, separate_from, config)
    fence_here = fence_distance(pose, config)

    place = placement(pose)
    origin = (pose.x_m, pose.y_m)
    single = single_target(goals, config.end_reach_m, origin)
    px = py = None  # (S, K + 1) each, when needed; column 0 is the pose itself
    if n_near or binding or fence_here is not None or not single:
        px, py, gx, gy = _placed(place, config, shape)
        ex, ey = px[:, -1], py[:, -1]
    else:
        ex, ey = place @ config.end_hom_m  # the prediction points (S,) only

    ok_by_rule: dict[Rule, np.ndarray] = {}  # (S, K + 1) per rule
    clear = legal = None
    if n_near:
        if config.row_of is None:  # (O, S * (K + 1)); the rule per rollout too when compiled
            clear, ok_by_rule[Rule.OBSTACLE], distance, legal = _obstacle_rule(px, py, snapshot, keep, near, config,
                                                                                shape)
        else:  # computed on the distinct rollouts only, then spread to all
            ok_by_rule[Rule.OBSTACLE], distance, clear = _obstacle_terms(gx, gy, near, config)
    else:
        distance = no_obstacle_in_reach(config)
    if binding:
        ok_by_rule[Rule.SEPARATION] = separation_ok(px, py, config.times_s, pose, binding, config)
    if fence_here is not None:
        ok_by_rule[Rule.GEOFENCE] = fence_ok(px, py, config.fence_m, fence_here)

    if legal is None or len(ok_by_rule) > 1:
        legal = legal_rollouts(ok_by_rule, config)
    if not np.count_nonzero(legal) or _only_hover(legal, config, scheduled_speed_m_s):
        if cautious:
            return None
        if near is None:
            near = snapshot.near(pose.x_m, pose.y_m, reach, config.horizon_s)
        if clear is not None and config.row_of is not None:  # the escape reads every rollout's
            clear = clear.reshape(len(clear), *gx.shape)[:, config.row_of].reshape(len(clear), -1)
        elif n_near and config.row_of is None and clear is None:  # the compiled pass left some out
            clear = inflated_clearance(px.ravel(), py.ravel(), config.point_times_s, near)
        final_heading = pose.heading_rad + config.final_dheading_rad
        heading = heading_from_ends(ex, ey, final_heading, goals, origin, px, py, single, _soonest(config))
        return no_legal_rollout(pose, goals, other, snapshot, near, config, ok_by_rule, heading, clear, separate_from)

    sightline = _sightline(pose, other, sighted, config, ex, ey, None if px is None else (gx, gy))
    speed = None
    if config.count > config.samples:
        speed = speed_scores(config, reference_speed_m_s(pose, goals, config, scheduled_speed_m_s))
    turn = turn_error(pose, goals, config)
    if _toward_only_hovers(legal, config, scheduled_speed_m_s, turn):
        turn = math.nan  # the turn-around preference would leave only hovers: drop it
    if single and kernels.pick is not None:  # the heading critic, the choice and the command in one call
        return pick(config, legal, turn, ex, ey, pose.heading_rad, goals.first_xy,
                    distance, sightline, speed)
    final_heading = pose.heading_rad + config.final_dheading_rad
    heading = heading_from_ends(ex, ey, final_heading, goals, origin, px, py, single, _soonest(config))
    best, total, n_legal = choose(config, legal, turn, heading, distance, sightline, speed)
    return command_for(config, best, heading, distance, sightline, total, n_legal)


def _soonest(config: DwaConfig) -> float:
    return _SOONEST_DEG if config.count > config.samples else 0.0


def _obstacle_rule(px: np.ndarray, py: np.ndarray, snapshot: ObstacleSnapshot, keep: np.ndarray | None,
                   near: ObstacleSnapshot | None, config: DwaConfig,
                   shape: tuple[int, int]) -> tuple[np.ndarray | None, np.ndarray, np.ndarray, np.ndarray | None]:
    """The clearances (O, S * (K + 1)) of the rollouts to the culled obstacles, the obstacle rule
    (S, K + 1), the distance critic (S,), and, compiled, the rule per rollout (S,).

    Compiled (:func:`kernels.obstacle_pass`): over the obstacles of ``snapshot`` that ``keep``
    marks (circles, then polygons), and the clearances are None when the pass left out those
    that cannot matter. Otherwise with numpy over ``near`` (the culled subset), and the rule per
    rollout is None (legal_rollouts works it out)."""
    if kernels.obstacle_pass is None:
        clear = inflated_clearance(px.ravel(), py.ravel(), config.point_times_s, near)
        ok, distance = obstacle_and_distance(clear, shape, config.distance_saturation_m)
        return clear, ok.reshape(shape), distance, None
    s = snapshot
    clear, ok, distance, legal, exact = kernels.obstacle_pass(
        one_layout(px.ravel()), one_layout(py.ravel()), config.point_times_s, s.circle_xy_m, s.circle_vel_m_s,
        s.circle_radius_m, s.circle_margin_m, s.poly_a_m, s.poly_b_m, s.poly_d_m, s.poly_inv_len2, s.poly_dx_per_dy,
        s.poly_vel_m_s, s.poly_margin_m, s.poly_centre_m, s.poly_bound_m, keep, shape[1], config.distance_saturation_m)
    return clear if exact else None, ok.reshape(shape), distance, legal



def warm_up_kernels() -> None:
    """Load (or compile) the compiled kernels of branches a throwaway tick at the station may not
    take: the heading critic over a goal window, the obstacle terms and the sight lines' frame,
    and the fused obstacle pass and choice near an obstacle, with the argument types a flight
    passes them (see companion.app.warmup)."""
    px = np.zeros((2, 3))
    goals = LocalGoals(np.array([[5.0, 0.0], [9.0, 0.0]]), (0.0, 0.0), 1.0, 1.0, ends_at_station=True)
    heading_from_ends(px[:, -1], px[:, -1], np.zeros(2), goals, (0.0, 0.0), px, px, False, _SOONEST_DEG)
    obstacle_and_distance(np.ones((1, 6)), (2, 3), 10.0)
    circle = ObstacleSnapshot.build([("c", 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)], [])
    sightline_scores(np.zeros((2, 2)), (5.0, 5.0), 1.0, circle)
    config = DwaConfig(speed_m_s=10.0, max_yaw_rate_rad_s=0.3, samples=3, dt_s=0.5, prediction_time_s=1.0, w_h=1.0,
                       w_d=1.0, w_s=1.0, sightline_cap_m=50.0)
    plan_step(Pose(0.0, 0.0, 0.0), (100.0, 0.0), OtherUav(0.0, 50.0, 0.0, 0.0), ObstacleSnapshot.build(
        [("c", 10.0, 20.0, 5.0, 1.0, 0.0, 0.0)], [("p", np.array([[0.0, 30.0], [9.0, 30.0], [9.0, 40.0]]), 1.0, 0.0,
                                                  0.0)]), config)


# With a speed window, an arriving rollout loses up to this much heading score for arriving late
# (the paper's constant-speed window keeps its ties).
_SOONEST_DEG = 5.0


def _only_hover(legal: np.ndarray, config: DwaConfig, scheduled_speed_m_s: float | None) -> bool:
    """With a speed window, a hover is legal wherever the vehicle already is (it never gets
    deeper into an inflated obstacle), so a vehicle that drifted into one would hover there for
    ever with every moving rollout illegal (small_reference over MAVLink: b for 500 s). Unless
    its timed route holds it still, that is no legal rollout: recover as the paper's window does."""
    if config.speed_samples == 1 or config.min_speed_m_s > 0.0:  # every rollout moves (cruise > 0)
        return False
    moving = config.speeds_m_s > 0.0
    if scheduled_speed_m_s is not None and scheduled_speed_m_s < 0.5 * float(config.speeds_m_s[moving].min()):
        return False  # the plan asks for a wait here
    return not np.count_nonzero(legal & moving)


def _toward_only_hovers(legal: np.ndarray, config: DwaConfig, scheduled_speed_m_s: float | None,
                        turn_error_rad: float) -> bool:
    """Whether the turn-around preference (:func:`legality.commit_turn`) would leave only hovers
    while a moving rollout is legal. It drops itself when it would leave no legal rollout; with
    a speed window, only hovers is the same (see :func:`_only_hover`). Otherwise a vehicle in a
    pocket with its goal far to one side turns that way in place until nothing is legal, the
    spin recovery turns it back, and again until the time limit, while moving rollouts to the
    other side were legal throughout. Unless its timed route holds it still."""
    if math.isnan(turn_error_rad) or config.speed_samples == 1 or config.min_speed_m_s > 0.0:
        return False
    moving = config.speeds_m_s > 0.0
    if scheduled_speed_m_s is not None and scheduled_speed_m_s < 0.5 * float(config.speeds_m_s[moving].min()):
        return False
    toward = config.yaw_rates_rad_s * turn_error_rad >= 0.0
    return not np.count_nonzero(legal & moving & toward) and bool(np.count_nonzero(legal & moving))


def _placed(place: np.ndarray, config: DwaConfig,
            shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every rollout placed at the pose (px, py (S, K + 1)) and the distinct ones (gx, gy (G, K + 1);
    the same arrays when all differ)."""
    if config.row_of is None:
        xy = place @ config.body_hom_m
        px, py = xy[0].reshape(shape), xy[1].reshape(shape)
        return px, py, px, py
    xy = place @ config.geo_hom_m
    gx, gy = xy[0].reshape(-1, shape[1]), xy[1].reshape(-1, shape[1])
    return gx[config.row_of], gy[config.row_of], gx, gy


def _obstacle_terms(gx: np.ndarray, gy: np.ndarray, near: ObstacleSnapshot,
                    config: DwaConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The obstacle rule (S, K + 1) and the distance critic (S,), computed on the distinct
    rollouts (gx, gy) and spread to every rollout, and their clearances (O, G * (K + 1))."""
    g_shape = gx.shape
    clear = inflated_clearance(gx.ravel(), gy.ravel(), config.geo_point_times_s, near)
    ok, distance = obstacle_and_distance(clear, g_shape, config.distance_saturation_m)
    row_of = config.row_of
    return ok.reshape(g_shape)[row_of], distance[row_of], clear


def _sightline(pose: Pose, other: OtherUav | None, snapshot: ObstacleSnapshot, config: DwaConfig, ex: np.ndarray,
               ey: np.ndarray, distinct: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray | None:
    """S for every rollout, computed on the distinct prediction points when some coincide."""
    if config.row_of is None or distinct is None:
        return sightline_term(pose, other, snapshot, config, ex, ey)
    gx, gy = distinct
    sightline = sightline_term(pose, other, snapshot, config, gx[:, -1], gy[:, -1])
    return None if sightline is None else sightline[config.row_of]
