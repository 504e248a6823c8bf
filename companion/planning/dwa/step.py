"""plan_step: one BDWA decision, wiring rollouts, legality, critics and evaluation together; the
kernels are the config's :class:`.Backend`."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from companion.planning.dwa.backend import DEFAULT
from companion.planning.dwa.config import DwaConfig
from companion.planning.dwa.distance import no_obstacle_in_reach
from companion.planning.dwa.evaluate import Critics
from companion.planning.dwa.heading import single_target
from companion.planning.dwa.legality import (Rule, binding_uavs, fence_distance, fence_ok, legal_rollouts,
                                             separation_ok, turn_error)
from companion.planning.dwa.recovery import Stuck, no_legal_rollout
from companion.planning.dwa.shapes import lagged_points, placement
from companion.planning.dwa.sightline import sightline_term
from companion.planning.dwa.snapshot import Culled, ObstacleSnapshot, with_turned_back
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
    culled = None
    if config.count > config.samples:  # a speed window: keep clear of receding obstacles turning back too
        culled = _cull(pose, snapshot, config)  # only those in reach can bind, turned back or not
        cautious = with_turned_back(snapshot, pose.x_m, pose.y_m, culled.keep) if culled.count else snapshot
        if cautious is not snapshot:
            found = _step(pose, goals, other, cautious, snapshot, config, scheduled_speed_m_s, separate_from,
                          cautious=True)
            if found is not None:
                return found
    return _step(pose, goals, other, snapshot, snapshot, config, scheduled_speed_m_s, separate_from, culled=culled)


def _step(pose: Pose, goals: LocalGoals, other: OtherUav | None, snapshot: ObstacleSnapshot,
          sighted: ObstacleSnapshot, config: DwaConfig, scheduled_speed_m_s: float | None,
          separate_from: Sequence[OtherUav] | None, cautious: bool = False,
          culled: Culled | None = None) -> Command | NoLegalRollout | None:
    """:func:`plan_step` against ``snapshot``; the sightline term reads ``sighted`` (where the
    obstacles are predicted to be). ``cautious``: ``snapshot`` also has the receding obstacles
    turned back, a precaution only: when it leaves no legal move, None (the caller plans without
    it) rather than an escape from obstacles that are not coming, which can take the vehicle
    into a static one. ``culled``: ``snapshot``'s culling, when the caller has it.

    Reads as the algorithm: what can bind (culling), the window's rollouts, the rules, then the
    critics and the pick; no legal rollout goes to :func:`.recovery.no_legal_rollout`."""
    backend = config.backend
    scene = _Scene.of(pose, goals, snapshot if culled is None else culled, config,
                      separate_from if separate_from is not None else () if other is None else (other,))
    window = _Window.of(pose, scene, config)
    rules = _rules(pose, scene, window, config)
    if rules.legal is not config.all_legal and (not np.count_nonzero(rules.legal)
                                                or _only_hover(rules.legal, config, scheduled_speed_m_s)):
        if cautious:
            return None
        return _recover(pose, goals, other, scene, window, rules, config)
    critics = _critics(pose, goals, other, sighted, window, rules, config, scheduled_speed_m_s)
    if scene.single:  # the heading critic, the choice and the command in one call
        return backend.pick(config, critics, window.ex, window.ey, pose.heading_rad, goals.first_xy)
    return backend.pick_goals(config, critics, window.ex, window.ey, pose.heading_rad, window.gx, window.gy, goals,
                              _soonest(config))


class _Scene(NamedTuple):
    """What can bind this tick: the obstacles within reach, the UAVs whose separation can bind,
    the pose's distance inside the fence (None: out of reach), and whether the heading critic
    scores every rollout toward the first goal (:func:`.heading.single_target`)."""

    culled: Culled
    separate_from: Sequence[OtherUav]
    binding: tuple[OtherUav, ...]
    fence_here: float | None
    single: bool

    @classmethod
    def of(cls, pose: Pose, goals: LocalGoals, snapshot: ObstacleSnapshot | Culled, config: DwaConfig,
           separate_from: Sequence[OtherUav]) -> "_Scene":
        """``snapshot``: the obstacles, or their culling already made (:func:`_cull`)."""
        return cls(snapshot if isinstance(snapshot, Culled) else _cull(pose, snapshot, config), separate_from,
                   binding_uavs(pose, separate_from, config), fence_distance(pose, config),
                   single_target(goals, config.end_reach_m, (pose.x_m, pose.y_m)))


def _cull(pose: Pose, snapshot: ObstacleSnapshot, config: DwaConfig) -> Culled:
    """The obstacles a rollout of the window can reach, or come within the distance critic's
    saturation of, over the horizon."""
    return config.backend.cull(snapshot, pose.x_m, pose.y_m, config.reach_m + config.distance_saturation_m,
                               config.horizon_s)


class _Window:
    """The window's rollouts placed at the pose: the prediction points (ex, ey) (S,), and the
    distinct rollouts (gx, gy) (G, K + 1) only when a rule or the goal window reads them (None
    otherwise: in open air only the S prediction points are placed). The whole rollouts (px, py)
    (S, K + 1) are the distinct ones spread by ``config.row_of``, on first read (the fused pick
    and the obstacle rule read the distinct ones). Column 0 is the pose itself."""

    __slots__ = ("ex", "ey", "gx", "gy", "_px", "_py", "_row_of")

    def __init__(self, ex: np.ndarray, ey: np.ndarray, gx: np.ndarray | None, gy: np.ndarray | None,
                 row_of: np.ndarray | None) -> None:
        self.ex, self.ey, self.gx, self.gy, self._row_of = ex, ey, gx, gy, row_of
        self._px, self._py = (gx, gy) if row_of is None else (None, None)

    @property
    def px(self) -> np.ndarray | None:
        return self._spread()[0]

    @property
    def py(self) -> np.ndarray | None:
        return self._spread()[1]

    def _spread(self) -> tuple[np.ndarray | None, np.ndarray | None]:
        if self._px is None and self.gx is not None:
            self._px, self._py = self.gx.take(self._row_of, axis=0), self.gy.take(self._row_of, axis=0)
        return self._px, self._py

    @classmethod
    def of(cls, pose: Pose, scene: _Scene, config: DwaConfig) -> "_Window":
        place = placement(pose)
        if scene.culled.count or scene.binding or scene.fence_here is not None or not scene.single:
            # the distinct rollouts' points (2, G * (K + 1)): every rollout when all differ
            xy = place @ (config.body_hom_m if config.row_of is None else config.geo_hom_m)
            n_k = config.steps + 1
            ends = xy.take(config.end_points, axis=1)  # every rollout's prediction point, in one call
            return cls(ends[0], ends[1], xy[0].reshape(-1, n_k), xy[1].reshape(-1, n_k), config.row_of)
        ex, ey = place @ config.end_hom_m
        return cls(ex, ey, None, None, None)


class _Rules(NamedTuple):
    """The rules' verdicts: each rule's mask per rollout point (S, K + 1), the clearances to the
    culled obstacles (None when none is in reach, or the compiled pass left out those that
    cannot matter), D (S,), and which rollouts obey every rule (S,)."""

    ok_by_rule: dict[Rule, np.ndarray]
    clear: np.ndarray | None
    distance: np.ndarray
    legal: np.ndarray


def _rules(pose: Pose, scene: _Scene, window: _Window, config: DwaConfig) -> _Rules:
    ok_by_rule: dict[Rule, np.ndarray] = {}
    clear = legal = None
    if scene.culled.count:
        if config.row_of is None:  # (O, S * (K + 1)); the rule per rollout too when compiled
            clear, ok_by_rule[Rule.OBSTACLE], distance, legal = config.backend.obstacle_rule(
                window.px, window.py, scene.culled, config)
        else:  # computed on the distinct rollouts only (clear: (O, G * (K + 1))), then spread to all
            clear, ok, distance, legal = config.backend.obstacle_rule(window.gx, window.gy, scene.culled, config,
                                                                      config.geo_point_times_s)
            row_of = config.row_of
            # take: a fancy index of a 2-D boolean array costs five times as much
            ok_by_rule[Rule.OBSTACLE], distance = ok.take(row_of, axis=0), distance[row_of]
            legal = None if legal is None else legal[row_of]
    else:
        distance = no_obstacle_in_reach(config)
    if scene.binding:
        ok_by_rule[Rule.SEPARATION] = _separation(pose, scene, window, config)
    if scene.fence_here is not None:
        ok_by_rule[Rule.GEOFENCE] = fence_ok(window.px, window.py, config.fence_m, scene.fence_here)
    if legal is None or len(ok_by_rule) > 1:
        legal = legal_rollouts(ok_by_rule, config)
    return _Rules(ok_by_rule, clear, distance, legal)


def _recover(pose: Pose, goals: LocalGoals, other: OtherUav | None, scene: _Scene, window: _Window, rules: _Rules,
             config: DwaConfig) -> NoLegalRollout:
    """No legal rollout: the escape reads every rollout's heading critic and clearances (worked
    out only then)."""
    near = scene.culled.subset  # built on first use

    def clearances() -> np.ndarray | None:
        clear = rules.clear
        if scene.culled.count and clear is None:  # the compiled pass left some out
            if config.row_of is None:
                return config.backend.inflated_clearance(window.px.ravel(), window.py.ravel(), config.point_times_s,
                                                         near())
            clear = config.backend.inflated_clearance(window.gx.ravel(), window.gy.ravel(), config.geo_point_times_s,
                                                      near())
        if clear is not None and config.row_of is not None:  # the escape reads every rollout's
            return clear.reshape(len(clear), *window.gx.shape)[:, config.row_of].reshape(len(clear), -1)
        return clear

    def heading() -> np.ndarray:
        return config.backend.heading_from_ends(window.ex, window.ey, pose.heading_rad + config.final_dheading_rad,
                                                goals, (pose.x_m, pose.y_m), window.px, window.py, scene.single,
                                                _soonest(config))

    def lagged_clearances() -> np.ndarray | None:
        xy = lagged_points(pose, config) if scene.culled.count else None
        if xy is None:
            return None
        return config.backend.inflated_clearance(xy[0], xy[1], config.point_times_s, near())

    def bare_separation() -> np.ndarray | None:
        return _separation(pose, scene, window, config, courtesy=False) if scene.binding else None

    stuck = Stuck(rules.ok_by_rule, heading, near, clearances, lagged_clearances, bare_separation)
    return no_legal_rollout(pose, goals, other, scene.culled.snapshot, config, stuck, scene.separate_from)


def _separation(pose: Pose, scene: _Scene, window: _Window, config: DwaConfig, courtesy: bool = True) -> np.ndarray:
    """The separation rule (S, K + 1) from the UAVs that can bind, on the rollouts and, for a
    plant that lags, on its flight of them too (:func:`.shapes.lagged_rollouts`): it flies wide
    of a turn by up to 17 m, far more than the separation's margin, and a turn that keeps the
    separation on the rollout loses it as flown (``courtesy``: see :func:`.legality.kept_from`)."""
    xy = lagged_points(pose, config)
    if xy is None:
        return separation_ok(window.px, window.py, config.times_s, pose, scene.binding, config, courtesy)
    shape = window.px.shape  # both in one array operation: (2 S, K + 1)
    ok = separation_ok(np.concatenate([window.px, xy[0].reshape(shape)]),
                       np.concatenate([window.py, xy[1].reshape(shape)]), config.times_s, pose, scene.binding,
                       config, courtesy)
    return ok[:shape[0]] & ok[shape[0]:]


def _critics(pose: Pose, goals: LocalGoals, other: OtherUav | None, sighted: ObstacleSnapshot, window: _Window,
             rules: _Rules, config: DwaConfig, scheduled_speed_m_s: float | None) -> Critics:
    """The critics besides the heading (which the pick may fuse with the choice), and the
    turn-around preference."""
    distinct = None if window.gx is None else (window.gx, window.gy)
    sightline = _sightline(pose, other, sighted, config, window.ex, window.ey, distinct)
    speed = None
    if config.count > config.samples:
        speed = speed_scores(config, reference_speed_m_s(pose, goals, config, scheduled_speed_m_s))
    turn = turn_error(pose, goals, config)
    if _toward_only_hovers(rules.legal, config, scheduled_speed_m_s, turn):
        turn = math.nan  # the turn-around preference would leave only hovers: drop it
    return Critics(rules.legal, turn, rules.distance, sightline, speed)


def _soonest(config: DwaConfig) -> float:
    return _SOONEST_DEG if config.count > config.samples else 0.0


def warm_up_kernels() -> None:
    """Load (or compile) the compiled kernels of branches a throwaway tick at the station may not
    take: the heading critic over a goal window, the obstacle terms and the sight lines' frame,
    the hover check's braking segment next to an obstacle, and the fused obstacle pass and
    choice near an obstacle, with the argument types a flight passes them (see
    companion.app.warmup), on the default backend (what a config gets); the fused pick over a
    goal window too."""
    px = np.zeros((2, 3))
    goals = LocalGoals(np.array([[5.0, 0.0], [9.0, 0.0]]), (0.0, 0.0), 1.0, 1.0, ends_at_station=True)
    DEFAULT.heading_from_ends(px[:, -1], px[:, -1], np.zeros(2), goals, (0.0, 0.0), px, px, False, _SOONEST_DEG)
    DEFAULT.obstacle_and_distance(np.ones((1, 6)), (2, 3), 10.0)
    circle = ObstacleSnapshot.build([("c", 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)], [])
    ends = np.zeros((2, 2))
    DEFAULT.sightline_depths(ends[:, 0], ends[:, 1], (5.0, 5.0), 1.0, circle)
    DEFAULT.braking_checks(np.zeros(2), np.zeros(2), np.zeros(3), circle)
    config = DwaConfig(speed_m_s=10.0, max_yaw_rate_rad_s=0.3, samples=3, dt_s=0.5, prediction_time_s=1.0, w_h=1.0,
                       w_d=1.0, w_s=1.0, sightline_cap_m=50.0)
    plan_step(Pose(0.0, 0.0, 0.0), (100.0, 0.0), OtherUav(0.0, 50.0, 0.0, 0.0), ObstacleSnapshot.build(
        [("c", 10.0, 20.0, 5.0, 1.0, 0.0, 0.0)], [("p", np.array([[0.0, 30.0], [9.0, 30.0], [9.0, 40.0]]), 1.0, 0.0,
                                                  0.0)]), config)
    plan_step(Pose(0.0, 0.0, 0.0), goals, None, ObstacleSnapshot.build([], []), config)  # the goal window's pick
    # boxed in by a ring of circles and a polygon: the recovery's spin checks
    ring = [(f"r{i}", 6.0 * math.cos(a), 6.0 * math.sin(a), 2.0, 0.5, 0.0, 0.0)
            for i, a in enumerate(np.arange(12) / 2.0)]
    plan_step(Pose(0.0, 0.0, 0.0), (100.0, 0.0), None, ObstacleSnapshot.build(
        ring, [("p", np.array([[-9.0, -1.0], [-7.0, -1.0], [-7.0, 1.0]]), 0.5, 0.0, 0.0)]), config)


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
    if scheduled_speed_m_s is not None and scheduled_speed_m_s < 0.5 * config.slowest_move_m_s:
        return False  # the plan asks for a wait here
    return not np.count_nonzero(legal & config.moving_rollouts)


def _toward_only_hovers(legal: np.ndarray, config: DwaConfig, scheduled_speed_m_s: float | None,
                        turn_error_rad: float) -> bool:
    """Whether the turn-around preference (:func:`legality.commit_turn`) would leave only hovers
    while a moving rollout is legal. It drops itself when it would leave no legal rollout; with
    a speed window, only hovers is the same (see :func:`_only_hover`). Otherwise a vehicle in a
    pocket with its goal far to one side turns that way in place until nothing is legal, the
    spin recovery turns it back, and again until the time limit, while moving rollouts to the
    other side were legal throughout. Unless its timed route holds it still."""
    if (math.isnan(turn_error_rad) or config.speed_samples == 1 or config.min_speed_m_s > 0.0
            or legal is config.all_legal):  # every rollout legal: the straight moving ones too
        return False
    moving = config.moving_rollouts
    if scheduled_speed_m_s is not None and scheduled_speed_m_s < 0.5 * config.slowest_move_m_s:
        return False
    toward = config.yaw_rates_rad_s * turn_error_rad >= 0.0
    return not np.count_nonzero(legal & moving & toward) and bool(np.count_nonzero(legal & moving))


def _sightline(pose: Pose, other: OtherUav | None, snapshot: ObstacleSnapshot, config: DwaConfig, ex: np.ndarray,
               ey: np.ndarray, distinct: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray | None:
    """S for every rollout, computed on the distinct prediction points when some coincide."""
    if config.row_of is None or distinct is None:
        return sightline_term(pose, other, snapshot, config, ex, ey)
    gx, gy = distinct
    sightline = sightline_term(pose, other, snapshot, config, gx[:, -1], gy[:, -1])
    return None if sightline is None else sightline[config.row_of]
