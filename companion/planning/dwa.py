"""BDWA: one vectorised dynamic-window step with three critics (paper section IV, SPEC §1).

    plan_step(pose, goals, other, snapshot, config) -> Command | NoLegalRollout

The vehicle flies at constant speed v; only the yaw rate is chosen. ``config.samples`` yaw rates
span [-v/r, v/r]; each is rolled out for the prediction time p in steps of dt. Because v and the
samples are fixed, the rollout *shapes* are fixed: they are computed once in the body frame
(cumulative yaw, cos/sin, cumulative positions) when the config is built, and each tick only
rotates and translates them (one matrix product). Nothing loops over samples or steps.

Critics (nav2 DWB style: one term per concern, each normalised over the legal candidates by its
sum as in Fox et al. 1997, then weighted):

- heading H = 180 deg - |theta_i - theta_j| at the prediction point toward the local goal
  (toward the goal the tracker would hold there: see :class:`LocalGoals`);
- distance D = the rollout's minimum clearance to the inflated obstacles (moving ones predicted
  at constant velocity), saturated at ``distance_saturation_m``;
- sightline S = min(cap, max over true obstacles crossing the UAV-UAV sight segment of
  min(extent left, extent right)), 0 when nothing crosses (BDWA only).

Legality (a rollout that fails is discarded, never scored):

- no rollout point inside an inflated obstacle (the paper's rule). A vehicle that already is
  inside an inflated zone (a moving obstacle came to it) may only fly rollouts that never get
  deeper than it is now, so the planner leads it out instead of freezing it there;
- no rollout point closer than ``min_separation_m`` to the other UAV predicted at constant
  velocity (same relaxation when already closer). A hard rule rather than a penalty, because
  separation is a success criterion and a penalty can always be outbid by the other critics;
- no rollout point outside the geofence box (same relaxation when already outside).

When every rollout is illegal the result is :class:`NoLegalRollout`; the caller holds (a
multicopter can hover), unless the result carries an ``escape``: a rollout that stays clear
longer than hovering would, when something is coming at the vehicle.

Obstacle knowledge comes in as an :class:`ObstacleSnapshot`: what is known *now*, predicted
forward at constant velocity, identically in the headless runner and the live companion.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # only for the builder's signature; the core takes plain values
    from uav_model.mission import PlannerSettings, SafetySettings, VehicleSpec


@dataclass(frozen=True, slots=True)
class Pose:
    """Own state in the ENU mission frame; heading is a math angle (from +x, CCW)."""

    x_m: float
    y_m: float
    heading_rad: float


@dataclass(frozen=True, slots=True)
class OtherUav:
    """The other UAV as the link reports it; predicted at constant velocity."""

    x_m: float
    y_m: float
    vx_m_s: float
    vy_m_s: float
    arrived: bool = False  # parked at its station: still kept clear of, no longer hidden from


@dataclass(frozen=True, slots=True)
class Command:
    """The chosen first step: ENU yaw rate (CCW positive) at the constant forward speed."""

    yaw_rate_rad_s: float
    speed_m_s: float
    heading_score: float  # raw critic values of the chosen rollout, for logs
    distance_score: float
    sightline_score: float
    eval_score: float  # normalised, weighted total
    legal_count: int  # how many of the samples were legal


@dataclass(frozen=True, slots=True)
class NoLegalRollout:
    """Every sampled rollout breaks a rule within the horizon. The vehicle holds (hovers) this
    tick, unless ``recovery`` is given (yaw in place toward a heading from which a rollout is
    legal: a Command with speed 0) or ``escape`` (a rollout that stays clear longer than
    hovering would, when the hover point is not safe). At most one of the two is set."""

    reason: str
    escape: Command | None = None
    recovery: Command | None = None


@dataclass(frozen=True, eq=False)
class LocalGoals:
    """The current local goal and the nodes after it, for the heading critic.

    The paper scores the heading at the prediction point toward "the local goal". A rollout whose
    prediction point lies beyond the current node would then be rewarded for turning back to a
    node the vehicle is about to pass anyway: with p = 11 s (110 m ahead) and nodes that sit on
    the inflated edge, that is the "turning around in place" of the paper's Fig. 7. So each
    rollout is scored toward the goal the tracker would hold at its prediction point: a node
    counts as reached along the rollout when a rollout point comes within ``acceptance_radius_m``
    of it or the prediction point has passed it (the tracker's own two rules); the station,
    last, counts only within ``station_radius_m`` and then scores the full 180 deg.
    """

    nodes_xy: np.ndarray  # (G, 2): the current local goal first, then the ones after it
    prev_xy: tuple[float, float]  # the node before the current goal
    acceptance_radius_m: float
    station_radius_m: float
    ends_at_station: bool  # whether nodes_xy[-1] is the station

    # Derived once (a tracker reuses its windows across ticks): each node's predecessor and
    # squared reach radius, for heading_scores.
    prev_nodes_xy: np.ndarray = field(init=False, repr=False)  # (G, 2)
    radius2_m2: np.ndarray = field(init=False, repr=False)  # (G,)
    first_xy: tuple[float, float] = field(init=False, repr=False)  # nodes_xy[0] as floats

    def __post_init__(self) -> None:
        nodes = np.asarray(self.nodes_xy, dtype=float)
        radius = np.full(len(nodes), self.acceptance_radius_m)
        if self.ends_at_station:
            radius[-1] = self.station_radius_m
        object.__setattr__(self, "prev_nodes_xy", np.vstack([self.prev_xy, nodes[:-1]]))
        object.__setattr__(self, "radius2_m2", radius * radius)
        object.__setattr__(self, "first_xy", (float(nodes[0, 0]), float(nodes[0, 1])))

    @classmethod
    def single(cls, goal_xy: tuple[float, float]) -> "LocalGoals":
        """One goal and nothing after it: the paper's heading critic exactly."""
        return cls(np.asarray([goal_xy], dtype=float), (float(goal_xy[0]), float(goal_xy[1])),
                   0.0, 0.0, ends_at_station=False)


@dataclass(frozen=True, eq=False)
class DwaConfig:
    """Everything one BDWA step needs, with the fixed rollout shapes precomputed.

    ``distance_saturation_m``: D stops growing beyond this clearance from the inflated edge.
    With Fox's sum normalisation a critic's pull is its spread over the candidates divided by
    its mean, so an unsaturated D (weighted 0.6 against 0.37 for heading) dominates whenever an
    obstacle is in reach, yet says nothing useful: A* puts every node where the route turns right
    on the inflated edge, and the inflation margin already is the keep-out distance. Saturated,
    D only says "do not skim the edge" and is indifferent beyond. Default 10 m (one grid cell,
    two steps of travel). On the reference mission UAV a needs 477.1 / 477.8 / 479.1 / 480.7 s
    with 0 / 10 / 30 / 60 m: the larger it is, the further the vehicle keeps off its route.
    ``min_separation_m``: the planning separation from the other UAV (see from_settings).
    ``turnaround_deg``: see :func:`_commit_turn`; 180 disables the rule.
    ``fence_m``: the geofence box; rollout points must stay inside it (legality, like obstacles).
    """

    speed_m_s: float
    max_yaw_rate_rad_s: float
    samples: int
    dt_s: float
    prediction_time_s: float
    w_h: float
    w_d: float
    w_s: float
    sightline_cap_m: float
    distance_saturation_m: float = 10.0
    min_separation_m: float = 0.0
    turnaround_deg: float = 90.0
    fence_m: tuple[float, float, float, float] | None = None  # keep-in box (x0, y0, x1, y1)
    recovery_samples: int = 11  # yaw-rate samples per heading in the spin recovery; 0 disables it

    yaw_rates_rad_s: np.ndarray = field(init=False, repr=False)  # (S,)
    times_s: np.ndarray = field(init=False, repr=False)  # (K + 1,) 0, dt, ..., p
    body_xy_m: np.ndarray = field(init=False, repr=False)  # (S, K + 1, 2) from the origin, heading +x
    final_dheading_rad: np.ndarray = field(init=False, repr=False)  # (S,) heading change at p
    point_times_s: np.ndarray = field(init=False, repr=False)  # (S * (K + 1),) times of body_xy_m's points
    # body_xy_m as homogeneous columns (3, S * (K + 1)): [x; y; 1]. One (2, 3) @ (3, N) product
    # places every rollout point (see _placement), x and y each coming out contiguous.
    body_hom_m: np.ndarray = field(init=False, repr=False)
    end_hom_m: np.ndarray = field(init=False, repr=False)  # (3, S): the prediction points only
    # Plain numbers and constant rows the tick reads, derived once (a property would recompute).
    steps: int = field(init=False, repr=False)  # K
    horizon_s: float = field(init=False, repr=False)  # K dt
    reach_m: float = field(init=False, repr=False)  # how far a rollout goes: v K dt
    all_legal: np.ndarray = field(init=False, repr=False)  # (S,) all True
    saturated_m: np.ndarray = field(init=False, repr=False)  # (S,) all distance_saturation_m
    saturated_sums: tuple[float, ...] = field(init=False, repr=False)  # [n]: numpy's sum of n of them
    end_reach_m: float = field(init=False, repr=False)  # the farthest prediction point from the pose
    # Spin recovery: rollouts (R = J headings x recovery samples) that start after yawing in place
    # by rec_turn_rad (J headings one tick of full-rate yaw apart, all round), rec_delay_s later.
    rec_body_xy_m: np.ndarray = field(init=False, repr=False)  # (R, K + 1, 2)
    rec_turn_rad: np.ndarray = field(init=False, repr=False)  # (R,)
    rec_delay_s: np.ndarray = field(init=False, repr=False)  # (R,)
    rec_final_dheading_rad: np.ndarray = field(init=False, repr=False)  # (R,)
    rec_point_times_s: np.ndarray = field(init=False, repr=False)  # (R * (K + 1),)

    def __post_init__(self) -> None:
        if self.samples < 1 or self.dt_s <= 0 or self.prediction_time_s < self.dt_s or self.speed_m_s <= 0:
            raise ValueError("DwaConfig needs samples >= 1, speed > 0 and prediction_time_s >= dt_s > 0")
        steps = max(1, round(self.prediction_time_s / self.dt_s))
        w = (np.zeros(1) if self.samples == 1
             else np.linspace(-self.max_yaw_rate_rad_s, self.max_yaw_rate_rad_s, self.samples))
        t = self.dt_s * np.arange(0, steps + 1)
        # The plant advances yaw first, then moves along the new heading (uav_model.plant).
        dheading = np.outer(w, t[1:])
        step_m = self.speed_m_s * self.dt_s
        body = np.zeros((len(w), steps + 1, 2))
        body[:, 1:, 0] = np.cumsum(np.cos(dheading), axis=1) * step_m
        body[:, 1:, 1] = np.cumsum(np.sin(dheading), axis=1) * step_m
        rec = _recovery_shapes(body, dheading[:, -1], t, self.max_yaw_rate_rad_s, self.dt_s, self.recovery_samples)
        for name, value in (("yaw_rates_rad_s", w), ("times_s", t), ("body_xy_m", body),
                            ("final_dheading_rad", dheading[:, -1].copy()), ("point_times_s", np.tile(t, len(w))),
                            ("body_hom_m", _homogeneous(body.reshape(-1, 2))),
                            ("end_hom_m", _homogeneous(body[:, -1])), *rec.items()):
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        for name, value in (("all_legal", np.ones(len(w), dtype=bool)),
                            ("saturated_m", np.full(len(w), self.distance_saturation_m))):
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        object.__setattr__(self, "saturated_sums", tuple(float(self.saturated_m[:n].sum()) for n in range(len(w) + 1)))
        object.__setattr__(self, "end_reach_m", float(np.hypot(body[:, -1, 0], body[:, -1, 1]).max()))
        object.__setattr__(self, "steps", steps)
        object.__setattr__(self, "horizon_s", float(t[-1]))
        object.__setattr__(self, "reach_m", self.speed_m_s * float(t[-1]))

    @classmethod
    def from_settings(cls, planner: "PlannerSettings", vehicle: "VehicleSpec",
                      safety: "SafetySettings | None" = None, *, sightline: bool = True,
                      **overrides) -> "DwaConfig":
        """The config a mission gives one vehicle. ``sightline=False`` is plain DWA (w_s = 0)."""
        values = dict(
            speed_m_s=vehicle.speed_m_s,
            max_yaw_rate_rad_s=vehicle.max_yaw_rate_rad_s,
            samples=planner.yaw_rate_samples,
            dt_s=planner.dt_s,
            prediction_time_s=planner.prediction_time_for(vehicle),
            w_h=planner.weight_heading,
            w_d=planner.weight_distance,
            w_s=planner.weight_sightline if sightline else 0.0,
            sightline_cap_m=planner.sightline_cap_m,
            # One step of own travel on top of the success criterion: the other UAV's
            # constant-velocity prediction drifts from its real (turning) path within a tick.
            min_separation_m=(0.0 if safety is None
                              else safety.min_separation_m + vehicle.speed_m_s * planner.dt_s),
        )
        values.update(overrides)
        return cls(**values)

    @property
    def spin_time_s(self) -> float:
        """The longest yaw in place the recovery may ask for (half a turn)."""
        return float(self.rec_delay_s.max()) if self.rec_delay_s.size else 0.0


def _homogeneous(xy: np.ndarray) -> np.ndarray:
    """(N, 2) points as (3, N) homogeneous columns."""
    return np.ascontiguousarray(np.vstack([xy.T, np.ones(len(xy))]))


def _placement(pose: Pose) -> np.ndarray:
    """(2, 3): left-multiplying homogeneous body points by this turns them to the pose's heading
    and moves them to its position."""
    c, s = math.cos(pose.heading_rad), math.sin(pose.heading_rad)
    return np.array([[c, -s, pose.x_m], [s, c, pose.y_m]])


def _recovery_shapes(body: np.ndarray, final_dheading: np.ndarray, t: np.ndarray, max_yaw_rate: float,
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


@dataclass(frozen=True, eq=False)
class ObstacleSnapshot:
    """Obstacles as known now, as arrays (ENU m, m/s), ready for the vectorised critics.

    Circles are exact (centre + true radius + margin). Every other shape is its true polygon:
    edge e of polygon p runs from ``poly_a_m[p, e]`` to ``poly_b_m[p, e]``.
    Polygons with fewer edges than the largest are padded with zero-length edges at their first
    vertex, which change neither a distance nor a crossing count, so that every reduction over
    a polygon's edges is one reduction over axis 1. The inflated shape is "true shape + margin"
    (the round-joined buffer the world uses), so the clearance to it is the distance to the true
    edges minus the margin. Each obstacle carries the velocity it is predicted with (zero when
    static). Build with :meth:`build`.
    """

    circle_ids: tuple[str, ...]
    circle_xy_m: np.ndarray  # (C, 2)
    circle_radius_m: np.ndarray  # (C,) true radius
    circle_margin_m: np.ndarray  # (C,)
    circle_vel_m_s: np.ndarray  # (C, 2)
    poly_ids: tuple[str, ...]
    poly_a_m: np.ndarray  # (P, E, 2) edge start points = the polygon's vertices (padded)
    poly_b_m: np.ndarray  # (P, E, 2) edge end points (= start for padding)
    poly_margin_m: np.ndarray  # (P,)
    poly_centre_m: np.ndarray  # (P, 2) a point and a radius that bound each true polygon
    poly_bound_m: np.ndarray  # (P,)
    poly_vel_m_s: np.ndarray  # (P, 2)

    # Derived once per snapshot. Per obstacle (circles, then polygons): a disc bounding the
    # inflated shape, and its speed. Per edge: 1/length^2 and dx/dy (point-in-polygon test).
    bound_xy_m: np.ndarray = field(init=False, repr=False)
    bound_radius_m: np.ndarray = field(init=False, repr=False)
    speed_m_s: np.ndarray = field(init=False, repr=False)
    poly_d_m: np.ndarray = field(init=False, repr=False)  # (P, E, 2) edge vectors
    poly_inv_len2: np.ndarray = field(init=False, repr=False)
    poly_dx_per_dy: np.ndarray = field(init=False, repr=False)
    polygons_move: bool = field(init=False, repr=False)
    _subsets: dict = field(init=False, repr=False)  # near() results by keep-mask: a cache
    # (rows that move, names of the fields that differ, cache) shared by snapshots that differ
    # only in those rows and fields (the headless runner's per-tick snapshots: the moving
    # obstacles translated). _take then builds a subset of unmoved obstacles once for all of
    # them, and otherwise indexes only the fields that differ. None: not shared.
    _shared: tuple[np.ndarray, frozenset, dict] | None = field(init=False, repr=False)

    def __post_init__(self) -> None:
        def put(name, value):
            object.__setattr__(self, name, value)
        put("bound_xy_m", np.concatenate([self.circle_xy_m, self.poly_centre_m]))
        put("bound_radius_m", np.concatenate([self.circle_radius_m + self.circle_margin_m,
                                              self.poly_bound_m + self.poly_margin_m]))
        vel = np.concatenate([self.circle_vel_m_s, self.poly_vel_m_s])
        put("speed_m_s", np.hypot(vel[:, 0], vel[:, 1]))
        put("poly_d_m", self.poly_b_m - self.poly_a_m)
        dx, dy = self.poly_d_m[..., 0], self.poly_d_m[..., 1]
        put("poly_inv_len2", 1.0 / np.maximum(dx * dx + dy * dy, 1e-12))
        put("poly_dx_per_dy", dx / np.where(dy == 0.0, 1.0, dy))
        put("polygons_move", bool(np.any(self.poly_vel_m_s)))
        put("_subsets", {})
        put("_shared", None)

    @property
    def count(self) -> int:
        return len(self.circle_ids) + len(self.poly_ids)

    @property
    def ids(self) -> tuple[str, ...]:
        return self.circle_ids + self.poly_ids

    def vertices(self, i: int) -> np.ndarray:
        """The true vertices (N, 2) of polygon i, without padding."""
        n = int(np.count_nonzero(np.any(self.poly_d_m[i] != 0.0, axis=1)))
        return self.poly_a_m[i, :n]

    @staticmethod
    def build(circles: list[tuple[str, float, float, float, float, float, float]],
              polygons: list[tuple[str, np.ndarray, float, float, float]]) -> "ObstacleSnapshot":
        """``circles``: (id, x, y, radius, margin, vx, vy); ``polygons``: (id, vertices (N, 2)
        without the closing repeat, margin, vx, vy); all at the current time."""
        c = np.asarray([row[1:] for row in circles], dtype=float).reshape(-1, 6)
        verts = [np.asarray(row[1], dtype=float) for row in polygons]
        edges = max((len(v) for v in verts), default=0)
        a = np.zeros((len(verts), edges, 2))
        b = np.zeros((len(verts), edges, 2))
        for i, v in enumerate(verts):
            a[i, :len(v)] = v
            a[i, len(v):] = v[0]
            b[i] = a[i]
            b[i, :len(v)] = np.roll(v, -1, axis=0)
        centres = np.asarray([v.mean(axis=0) for v in verts]).reshape(-1, 2)
        return ObstacleSnapshot(
            circle_ids=tuple(str(row[0]) for row in circles),
            circle_xy_m=c[:, 0:2].copy(), circle_radius_m=c[:, 2].copy(),
            circle_margin_m=c[:, 3].copy(), circle_vel_m_s=c[:, 4:6].copy(),
            poly_ids=tuple(str(row[0]) for row in polygons), poly_a_m=a, poly_b_m=b,
            poly_margin_m=np.asarray([row[2] for row in polygons], dtype=float),
            poly_centre_m=centres,
            poly_bound_m=np.asarray([np.hypot(*(v - m).T).max() for v, m in zip(verts, centres)], dtype=float),
            poly_vel_m_s=np.asarray([row[3:5] for row in polygons], dtype=float).reshape(-1, 2),
        )

    def merged(self, other: "ObstacleSnapshot") -> "ObstacleSnapshot":
        """Both snapshots' obstacles in one (e.g. prepared static ones + this tick's moving ones).
        The derived arrays are joined too, not derived again: this runs every tick."""
        if not other.count:
            return self
        if not self.count:
            return other
        edges = max(self.poly_a_m.shape[1], other.poly_a_m.shape[1])
        cat = np.concatenate
        values = {"circle_ids": self.circle_ids + other.circle_ids, "poly_ids": self.poly_ids + other.poly_ids,
                  "polygons_move": self.polygons_move or other.polygons_move, "_subsets": {}, "_shared": None}
        for name in ("circle_xy_m", "circle_radius_m", "circle_margin_m", "circle_vel_m_s", "poly_margin_m",
                     "poly_centre_m", "poly_bound_m", "poly_vel_m_s"):
            values[name] = cat([getattr(self, name), getattr(other, name)])
        n1, n2 = len(self.circle_ids), len(other.circle_ids)
        for name in ("bound_xy_m", "bound_radius_m", "speed_m_s"):  # circles first, then polygons
            a, b = getattr(self, name), getattr(other, name)
            values[name] = cat([a[:n1], b[:n2], a[n1:], b[n2:]])
        values["poly_a_m"] = cat([_pad_edges(self.poly_a_m, edges), _pad_edges(other.poly_a_m, edges)])
        values["poly_b_m"] = cat([_pad_edges(self.poly_b_m, edges, self.poly_a_m),
                                  _pad_edges(other.poly_b_m, edges, other.poly_a_m)])
        values["poly_d_m"] = cat([_pad_edges(self.poly_d_m, edges, zeros=True),
                                  _pad_edges(other.poly_d_m, edges, zeros=True)])
        for name, fill in (("poly_inv_len2", 1e12), ("poly_dx_per_dy", 0.0)):  # what a zero-length edge gets
            a, b = getattr(self, name), getattr(other, name)
            values[name] = cat([_pad_columns(a, edges, fill), _pad_columns(b, edges, fill)])
        return _assemble(values)

    def near(self, x_m: float, y_m: float, reach_m: float, horizon_s: float,
             to_xy: tuple[float, float] | None = None) -> "ObstacleSnapshot":
        """Only the obstacles whose inflated shape can come within ``reach_m`` of (x, y) during
        ``horizon_s`` at their predicted velocity; the others cannot touch any rollout. With
        ``to_xy``: within ``reach_m`` of the segment (x, y) -> to_xy (sight lines)."""
        keep, kept = self.near_mask(x_m, y_m, reach_m, horizon_s, to_xy)
        if kept == len(keep):
            return self
        if not kept:
            return NO_OBSTACLES
        key = keep.tobytes()
        cached = self._subsets.get(key)
        if cached is None:
            cached = self._subsets[key] = self._take(keep, key)
        return cached

    def near_mask(self, x_m: float, y_m: float, reach_m: float, horizon_s: float,
                  to_xy: tuple[float, float] | None = None) -> tuple[np.ndarray, int]:
        """What :meth:`near` keeps, as a mask over the obstacles (circles, then polygons), and
        how many it keeps; for a caller that only indexes a few arrays."""
        bx, by = self.bound_xy_m[:, 0], self.bound_xy_m[:, 1]
        if to_xy is None:
            dx, dy = bx - x_m, by - y_m
            d = np.sqrt(dx * dx + dy * dy)
        else:
            d = _to_segment(bx, by, x_m, y_m, to_xy)
        keep = d - self.bound_radius_m - self.speed_m_s * horizon_s <= reach_m
        return keep, int(np.count_nonzero(keep))

    def _take(self, keep: np.ndarray, key: bytes) -> "ObstacleSnapshot":
        """The obstacles where ``keep`` (circles, then polygons) is true; ``key`` is
        ``keep.tobytes()``. Indexes the derived arrays too instead of deriving them again: this
        runs every tick for fresh snapshots."""
        n_c = len(self.circle_ids)
        kc, kp = keep[:n_c], keep[n_c:]

        def pick(names) -> dict:
            return {name: getattr(self, name)[keep if rows is _BOTH else kc if rows is _CIRCLE else kp]
                    for name, rows in _ROW_FIELDS.items() if name in names}

        def ids() -> dict:
            return {"circle_ids": tuple(i for i, k in zip(self.circle_ids, kc) if k),
                    "poly_ids": tuple(i for i, k in zip(self.poly_ids, kp) if k), "_subsets": {}, "_shared": None}

        def assemble(values: dict) -> "ObstacleSnapshot":
            return _assemble({**values, "polygons_move": bool(values["poly_vel_m_s"].any())})

        if self._shared is None:
            return assemble({**pick(_ROW_FIELDS), **ids()})
        moving_rows, moving_fields, cache = self._shared
        entry = cache.get(key)
        if entry is None:
            fixed = {**pick(_ROW_FIELDS.keys() - moving_fields), **ids()}
            whole = None
            if not np.any(keep & moving_rows):  # the same subset in every snapshot that shares the cache
                whole = assemble({**fixed, **pick(moving_fields)})
            entry = cache[key] = (fixed, whole)
        fixed, whole = entry
        if whole is not None:
            return whole
        return assemble({**fixed, **pick(moving_fields)})


# The array fields of a snapshot and the rows they have: one per circle, polygon, or obstacle
# (circles first, then polygons).
_CIRCLE, _POLYGON, _BOTH = "circle", "polygon", "both"
_ROW_FIELDS = {
    **dict.fromkeys(("circle_xy_m", "circle_radius_m", "circle_margin_m", "circle_vel_m_s"), _CIRCLE),
    **dict.fromkeys(("poly_a_m", "poly_b_m", "poly_margin_m", "poly_centre_m", "poly_bound_m", "poly_vel_m_s",
                     "poly_d_m", "poly_inv_len2", "poly_dx_per_dy"), _POLYGON),
    **dict.fromkeys(("bound_xy_m", "bound_radius_m", "speed_m_s"), _BOTH),
}


def _assemble(values: dict) -> ObstacleSnapshot:
    """A snapshot from every field, derived ones included (no __post_init__)."""
    out = object.__new__(ObstacleSnapshot)
    for name, value in values.items():
        object.__setattr__(out, name, value)
    return out


def _pad_columns(arr: np.ndarray, edges: int, fill: float) -> np.ndarray:
    missing = edges - arr.shape[1]
    return arr if missing <= 0 else np.concatenate([arr, np.full((arr.shape[0], missing), fill)], axis=1)


def _pad_edges(arr: np.ndarray, edges: int, starts: np.ndarray | None = None, zeros: bool = False) -> np.ndarray:
    """(P, E, 2) padded to ``edges`` along axis 1 with each polygon's first vertex (of
    ``starts`` when given), or with zeros: zero-length edges."""
    missing = edges - arr.shape[1]
    if missing <= 0:
        return arr
    if not len(arr) or zeros:
        return np.concatenate([arr, np.zeros((len(arr), missing, 2))], axis=1)
    first = (arr if starts is None else starts)[:, :1]
    return np.concatenate([arr, np.repeat(first, missing, axis=1)], axis=1)


NO_OBSTACLES = ObstacleSnapshot.build([], [])


def _to_segment(px: np.ndarray, py: np.ndarray, x_m: float, y_m: float, to_xy: tuple[float, float]) -> np.ndarray:
    """Distance from points (px, py) to the segment (x, y) -> to_xy."""
    dx, dy = to_xy[0] - x_m, to_xy[1] - y_m
    rx, ry = px - x_m, py - y_m
    len2 = dx * dx + dy * dy
    if len2 == 0.0:
        return np.hypot(rx, ry)
    u = np.minimum(np.maximum((rx * dx + ry * dy) / len2, 0.0), 1.0)
    return np.hypot(rx - u * dx, ry - u * dy)


def rollouts(pose: Pose, config: DwaConfig) -> tuple[np.ndarray, np.ndarray]:
    """All rollouts for ``pose``: points (S, K + 1, 2) at config.times_s (the first is the pose
    itself) and the headings (S,) at the prediction point."""
    xy = _placement(pose) @ config.body_hom_m  # (2, N)
    return np.stack([xy[0], xy[1]], axis=-1).reshape(config.body_xy_m.shape), pose.heading_rad + config.final_dheading_rad


def inflated_clearance(px: np.ndarray, py: np.ndarray, t_s: np.ndarray, snap: ObstacleSnapshot) -> np.ndarray:
    """Signed clearance (O, N) of N points (px, py) at times t_s (all (N,)) to each inflated
    obstacle predicted at constant velocity; negative inside. Rows: circles, then polygons.

    Obstacles run along the first axis and points along the second, so that every elementwise
    operation streams over the points and every reduction over obstacles or edges is a
    row-wise one: numpy is several times slower reducing a short last axis.
    """
    parts = []
    if snap.circle_ids:
        parts.append(_circle_distance(px, py, t_s, snap) - snap.circle_margin_m[:, None])
    if snap.poly_ids:
        parts.append(_polygon_signed_distance(px, py, t_s, snap) - snap.poly_margin_m[:, None])
    if not parts:
        return np.zeros((0, len(px)))
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


def _circle_distance(px: np.ndarray, py: np.ndarray, t_s: np.ndarray, snap: ObstacleSnapshot) -> np.ndarray:
    """Signed distance (C, N) from points at times t_s to each true circle, predicted."""
    c, v = snap.circle_xy_m, snap.circle_vel_m_s
    dx = px - c[:, 0:1]
    dy = py - c[:, 1:2]
    if np.any(v):
        dx -= v[:, 0:1] * t_s
        dy -= v[:, 1:2] * t_s
    return np.hypot(dx, dy) - snap.circle_radius_m[:, None]


def _polygon_signed_distance(px: np.ndarray, py: np.ndarray, t_s: np.ndarray,
                             snap: ObstacleSnapshot) -> np.ndarray:
    """Distance (P, N) from points at times t_s to each true polygon, negative inside
    (crossing number). A moving polygon is handled in its own frame: the points move by -v t.
    All work is on (P, E, N) arrays, in place where possible: this is the hot loop.
    """
    a, d = snap.poly_a_m, snap.poly_d_m
    abx, aby = d[..., 0:1], d[..., 1:2]  # (P, E, 1)
    qx, qy = px, py
    if snap.polygons_move:
        qx = px - (snap.poly_vel_m_s[:, 0:1] * t_s)[:, None, :]  # (P, 1, N)
        qy = py - (snap.poly_vel_m_s[:, 1:2] * t_s)[:, None, :]
    apx = qx - a[..., 0:1]  # (P, E, N)
    apy = qy - a[..., 1:2]
    # Crossing number (before apx/apy are reused): edges straddling the point's row whose
    # crossing lies right of the point. Compared on the raw coordinates, as the textbook test
    # does, so a point level with a vertex is counted consistently.
    straddle = (a[..., 1:2] > qy) != (snap.poly_b_m[..., 1:2] > qy)
    straddle &= apx < apy * snap.poly_dx_per_dy[..., None]
    inside = np.logical_xor.reduce(straddle, axis=1)
    # Distance to each edge segment, then the nearest edge of each polygon.
    u = apx * abx
    u += apy * aby
    u *= snap.poly_inv_len2[..., None]
    np.maximum(u, 0.0, out=u)  # clip to [0, 1]; np.clip costs more per call
    np.minimum(u, 1.0, out=u)
    apx -= u * abx
    apy -= u * aby
    apx *= apx
    apy *= apy
    apx += apy
    dist = np.sqrt(apx.min(axis=1))
    dist[inside] *= -1.0
    return dist


def sightline_scores(ends: np.ndarray, other_xy: tuple[float, float], t_s: float,
                     snap: ObstacleSnapshot) -> np.ndarray:
    """The sightline distance (S,) for sight segments ends[i] -> other_xy, uncapped.

    For each TRUE obstacle (predicted to ``t_s``) that the segment crosses, d_O is the smaller
    of the obstacle's extents left and right of the segment's line; the result is the largest
    d_O, or 0 when nothing crosses.
    """
    return _sightline_scores(ends[:, 0], ends[:, 1], other_xy, t_s, snap)


def _sightline_scores(ex: np.ndarray, ey: np.ndarray, other_xy: tuple[float, float], t_s: float,
                      snap: ObstacleSnapshot, keep: np.ndarray | None = None) -> np.ndarray:
    """sightline_scores for ends (ex, ey), each (S,), over the obstacles where ``keep`` (a mask,
    circles then polygons; all when None).

    Every sight segment ends at q = other_xy, so everything is measured from q: for a point
    w (relative to q), w . n_i is its signed distance from sight line i (n_i its unit left
    normal) and w . d_i its position along it (d_i = q - end_i). One (rows, 2) @ (2, 2S)
    product gives both for every circle centre, polygon vertex and edge vector at once; the
    rest is a handful of elementwise operations on the (rows, S) blocks.
    """
    qx, qy = other_xy
    dx = qx - ex
    dy = qy - ey
    n_s = len(ex)
    len2 = np.maximum(dx * dx + dy * dy, 1e-12)
    inv_len = 1.0 / np.sqrt(len2)
    basis = np.empty((2, 2 * n_s))  # [n | d]
    basis[0, :n_s] = -dy * inv_len
    basis[1, :n_s] = dx * inv_len
    basis[0, n_s:] = dx
    basis[1, n_s:] = dy
    c_xy, c_vel, c_r = snap.circle_xy_m, snap.circle_vel_m_s, snap.circle_radius_m
    p_a, p_d, p_vel = snap.poly_a_m, snap.poly_d_m, snap.poly_vel_m_s
    if keep is not None:
        kc, kp = keep[:len(c_r)], keep[len(c_r):]
        c_xy, c_vel, c_r = c_xy[kc], c_vel[kc], c_r[kc]
        p_a, p_d, p_vel = p_a[kp], p_d[kp], p_vel[kp]
    n_c, n_p = len(c_r), len(p_a)
    parts = []
    if n_c:
        parts.append(c_xy + (c_vel * t_s - (qx, qy)))
    if n_p:
        n_e = p_a.shape[1]
        shift = p_vel * t_s - (qx, qy)
        parts.append((p_a + shift[:, None, :]).reshape(-1, 2))  # vertices, from q
        parts.append(p_d.reshape(-1, 2))  # edge vectors
    m = (parts[0] if len(parts) == 1 else np.concatenate(parts)) @ basis
    best = np.zeros(n_s)
    if n_c:
        side, along = m[:n_c, :n_s], m[:n_c, n_s:]  # centre: from the line; along it, from q
        # The closest point of segment i to the centre: its position u in [0, 1] from the end.
        u = along / len2 + 1.0
        over = u - np.minimum(np.maximum(u, 0.0), 1.0)
        r = c_r[:, None]
        crosses = side * side + over * over * len2 < r * r
        best = np.where(crosses, r - np.abs(side), 0.0).max(axis=0)
    if n_p:
        k0, k1 = n_c + n_p * n_e, n_c + 2 * n_p * n_e
        sa, pa = m[n_c:k0, :n_s], m[n_c:k0, n_s:]  # each edge's start (a vertex)
        sd, pd = m[k0:k1, :n_s], m[k0:k1, n_s:]  # each edge's vector
        # An edge crosses the segment if it straddles the line at a point between the ends:
        # at k = sa / -sd along the edge, whose position along the line from q is pa + k pd,
        # in [-|d|^2, 0].
        straddle = (sa > 0.0) != (sa + sd > 0.0)
        w = pa + sa / np.where(straddle, -sd, 1.0) * pd
        straddle &= (w >= -len2) & (w <= 0.0)
        crossed = straddle.reshape(n_p, n_e, n_s).any(axis=1)  # (P, S)
        sa = sa.reshape(n_p, n_e, n_s)
        d_o = np.where(crossed, np.minimum(sa.max(axis=1), -sa.min(axis=1)), 0.0)
        best = np.maximum(best, d_o.max(axis=0))
    return best


def heading_scores(pts: np.ndarray, final_heading: np.ndarray, goals: LocalGoals) -> np.ndarray:
    """H (S,) in degrees: 180 - |heading - bearing to goal| at each prediction point, toward the
    goal the tracker would hold there (see :class:`LocalGoals`). ``pts``: rollouts (S, K + 1, 2)."""
    return _heading(pts[:, -1, 0], pts[:, -1, 1], final_heading, goals, pts[0, 0], pts[..., 0], pts[..., 1])


def _single_target(goals: LocalGoals, reach_m: float, origin: tuple[float, float]) -> bool:
    """Whether every rollout is scored toward the first goal, so that only the prediction points
    matter: one goal, and when it is the station, no prediction point (at most ``reach_m`` from
    ``origin``, the pose) can reach it."""
    if len(goals.nodes_xy) != 1:
        return False
    if not goals.ends_at_station:
        return True
    x0, y0 = origin
    return math.hypot(goals.first_xy[0] - x0, goals.first_xy[1] - y0) > reach_m + goals.station_radius_m


def _heading(ex: np.ndarray, ey: np.ndarray, final_heading: np.ndarray, goals: LocalGoals,
             origin: tuple[float, float], px: np.ndarray | None, py: np.ndarray | None,
             single: bool | None = None) -> np.ndarray:
    """heading_scores from the prediction points (ex, ey) (S,) leaving the pose ``origin``; the
    whole rollouts px, py (S, K + 1) are read only when not ``single`` (see _single_target)."""
    nodes = goals.nodes_xy
    count = len(nodes)
    at_station = None
    if single is None:
        x0, y0 = origin
        dx, dy = ex - x0, ey - y0
        single = _single_target(goals, math.sqrt(float((dx * dx + dy * dy).max())), origin)
    if single:
        tx, ty = goals.first_xy
    else:
        gx, gy = nodes[:, 0], nodes[:, 1]
        near2 = (((px.ravel() - gx[:, None]) ** 2 + (py.ravel() - gy[:, None]) ** 2)
                 .reshape(count, *px.shape).min(axis=2).T)  # (S, G)
        prev = goals.prev_nodes_xy
        passed = (ex[:, None] - gx) * (gx - prev[:, 0]) + (ey[:, None] - gy) * (gy - prev[:, 1]) > 0.0
        if goals.ends_at_station:
            passed[:, -1] = False  # the station is reached, never passed
        # How many goals in a row each rollout reaches: the first unreached one's index.
        reached = np.zeros((len(ex), count + 1), dtype=bool)
        np.logical_or(near2 <= goals.radius2_m2, passed, out=reached[:, :count])
        n_reached = reached.argmin(axis=1)
        if goals.ends_at_station:
            at_station = n_reached == count
        target = nodes[np.minimum(n_reached, count - 1)]
        tx, ty = target[:, 0], target[:, 1]
    bearing = np.arctan2(ty - ey, tx - ex)
    deviation = np.abs((final_heading - bearing + np.pi) % (2.0 * np.pi) - np.pi)
    heading = 180.0 - np.degrees(deviation)
    return heading if at_station is None else np.where(at_station, 180.0, heading)


def plan_step(pose: Pose, goals: LocalGoals | tuple[float, float], other: OtherUav | None,
              snapshot: ObstacleSnapshot, config: DwaConfig) -> Command | NoLegalRollout:
    """One BDWA decision: the best legal yaw rate toward the local goal, or NoLegalRollout.

    ``goals`` is a :class:`LocalGoals` window (what the fusion layer passes) or a bare (x, y).
    Every array here is small (31 x 23 points), so the cost is the number of numpy calls, not
    arithmetic: the whole rollouts are placed only when a rule or the goal window reads them
    (in open air only the 31 prediction points are), and each rule is skipped when it cannot bind.
    """
    if not isinstance(goals, LocalGoals):
        goals = LocalGoals.single(goals)
    times = config.times_s
    horizon = config.horizon_s
    shape = (config.samples, config.steps + 1)
    near = snapshot.near(pose.x_m, pose.y_m, config.reach_m + config.distance_saturation_m, horizon)
    # Separation can only bind when the other UAV's predicted path comes within reach.
    separation = other is not None and config.min_separation_m > 0 and (
        math.hypot(pose.x_m - other.x_m, pose.y_m - other.y_m) <= config.reach_m + config.min_separation_m
        + math.hypot(other.vx_m_s, other.vy_m_s) * horizon + 1.0)
    fence = config.fence_m
    fence_here = None  # distance to the fence, when a rollout can reach it
    if fence is not None:
        here = min(pose.x_m - fence[0], fence[2] - pose.x_m, pose.y_m - fence[1], fence[3] - pose.y_m)
        if here < config.reach_m:
            fence_here = here

    place = _placement(pose)
    origin = (pose.x_m, pose.y_m)
    single = _single_target(goals, config.end_reach_m, origin)
    px = py = None  # (S, K + 1) each, when needed; column 0 is the pose itself
    if near.count or separation or fence_here is not None or not single:
        xy = place @ config.body_hom_m
        px, py = xy[0].reshape(shape), xy[1].reshape(shape)
        ex, ey = px[:, -1], py[:, -1]
    else:
        ex, ey = place @ config.end_hom_m  # the prediction points (S,) only
    final_heading = pose.heading_rad + config.final_dheading_rad

    ok_by_rule: dict[str, np.ndarray] = {}  # (S, K + 1) per rule
    clear = None
    if near.count:
        clear = inflated_clearance(px.ravel(), py.ravel(), config.point_times_s, near)  # (O, S * (K + 1))
        lowest = clear.min(axis=0)
        if clear[:, 0].min() >= 0.0:  # outside every inflated obstacle: no rollout point may enter one
            ok = lowest >= -1e-9
        else:  # already inside one: never deeper than now
            ok = (clear >= np.minimum(clear[:, 0:1], 0.0) - 1e-9).all(axis=0)
        ok_by_rule["obstacle"] = ok.reshape(shape)
        distance = np.minimum(np.maximum(lowest.reshape(shape)[:, 1:].min(axis=1), 0.0), config.distance_saturation_m)
    else:
        distance = config.saturated_m
    if separation:
        ox = other.x_m + other.vx_m_s * times
        oy = other.y_m + other.vy_m_s * times
        limit = min(config.min_separation_m, math.hypot(pose.x_m - other.x_m, pose.y_m - other.y_m))
        ok_by_rule["separation"] = (px - ox) ** 2 + (py - oy) ** 2 >= (limit - 1e-6) ** 2
    if fence_here is not None:
        inside = np.minimum(np.minimum(px - fence[0], fence[2] - px), np.minimum(py - fence[1], fence[3] - py))
        ok_by_rule["geofence"] = inside >= min(fence_here, 0.0) - 1e-9

    ok_pts = None
    for ok in ok_by_rule.values():
        ok_pts = ok if ok_pts is None else ok_pts & ok
    legal = config.all_legal if ok_pts is None else ok_pts[:, 1:].all(axis=1)
    heading = _heading(ex, ey, final_heading, goals, origin, px, py, single)
    if not np.count_nonzero(legal):
        return _no_legal_rollout(pose, goals, other, snapshot, near, config, ok_by_rule, heading, clear)
    legal = _commit_turn(pose, goals, legal, config)

    sightline = _sightline(pose, other, snapshot, config, ex, ey)
    n_legal = int(np.count_nonzero(legal))
    total = _evaluate(config, legal, heading, distance, sightline, n_legal == config.samples)
    best = int(total.argmax())
    return _command(config, best, heading, distance, sightline, float(total[best]), n_legal)


def _command(config: DwaConfig, i: int, heading: np.ndarray, distance: np.ndarray, sightline: np.ndarray | None,
             total: float, legal_count: int) -> Command:
    return Command(yaw_rate_rad_s=float(config.yaw_rates_rad_s[i]), speed_m_s=config.speed_m_s,
                   heading_score=float(heading[i]), distance_score=float(distance[i]),
                   sightline_score=0.0 if sightline is None else float(sightline[i]),
                   eval_score=total, legal_count=legal_count)


def _no_legal_rollout(pose: Pose, goals: LocalGoals, other: OtherUav | None, snapshot: ObstacleSnapshot,
                      near: ObstacleSnapshot, config: DwaConfig, ok_by_rule: dict[str, np.ndarray],
                      heading: np.ndarray, clear: np.ndarray | None) -> NoLegalRollout:
    """Every rollout at cruise speed breaks a rule within the horizon: recover, hold or escape.

    1. Spin recovery (nav2's spin behaviour; a multicopter can yaw in place): the rollouts that
       start here after a yaw in place to another heading, under the same rules and critics,
       with moving obstacles and the other UAV predicted over the yaw time too and the hover
       point safe while yawing. The best one's heading is the target: yaw toward it, speed 0.
       Without this a vehicle in a pocket hovers with a fixed heading for ever.
    2. Hold, if the hover point stays clear of the inflated obstacles (moving ones predicted at
       constant velocity) and of the other UAV for a full spin plus a horizon.
    3. The hover point is going to be hit: the recovery judged on the TRUE footprints (the
       inflation margin is the reserve an emergency may use); else
    4. the rollout from the current heading that stays clear of the true footprints longest,
       if it lasts longer than hovering (the escape); else hold.
    """
    blocking = [rule for rule, ok in ok_by_rule.items() if not ok[:, 1:].all(axis=1).any()]
    what = ", ".join(blocking) if blocking else "no rollout satisfies all rules at once"
    reason = f"all {config.samples} rollouts break a rule within {config.prediction_time_s:g} s ({what})"
    dt, steps = config.dt_s, config.steps
    hover_steps = steps + round(config.spin_time_s / dt)
    t_hover = dt * np.arange(hover_steps + 1)
    field_h = snapshot.near(pose.x_m, pose.y_m, config.reach_m + config.distance_saturation_m, float(t_hover[-1]))
    margins = np.concatenate([field_h.circle_margin_m, field_h.poly_margin_m])[:, None]

    # The hover point over the long horizon, inflated and true; separation is never relaxed.
    hover_inf = np.ones(hover_steps + 1, dtype=bool)
    hover_true = hover_inf.copy()
    if field_h.count:
        hc = inflated_clearance(np.full(hover_steps + 1, pose.x_m), np.full(hover_steps + 1, pose.y_m), t_hover, field_h)
        floor_inf = np.minimum(hc[:, 0:1], 0.0)
        floor_true = np.minimum(hc[:, 0:1] + margins, 0.0)
        hover_inf &= (hc >= floor_inf - 1e-9).all(axis=0)
        hover_true &= (hc + margins >= floor_true - 1e-9).all(axis=0)
    sep_limit = None
    if other is not None and config.min_separation_m > 0:
        sep_limit = min(config.min_separation_m, math.hypot(pose.x_m - other.x_m, pose.y_m - other.y_m)) - 1e-6
        d2 = (other.x_m + other.vx_m_s * t_hover - pose.x_m) ** 2 + (other.y_m + other.vy_m_s * t_hover - pose.y_m) ** 2
        hover_inf &= d2 >= sep_limit ** 2
        hover_true &= d2 >= sep_limit ** 2
    hover_inf = np.logical_and.accumulate(hover_inf)  # clear up to step k
    hover_true = np.logical_and.accumulate(hover_true)

    if config.rec_delay_s.size:
        body = config.rec_body_xy_m
        pts = (body.reshape(-1, 2) @ _rotation(pose.heading_rad)).reshape(body.shape)
        pts += (pose.x_m, pose.y_m)
        px, py = pts[..., 0], pts[..., 1]
        n_r = len(pts)
        delay_k = np.rint(config.rec_delay_s / dt).astype(int)
        ok_inf = hover_inf[delay_k]
        ok_true = hover_true[delay_k]
        if field_h.count:
            rc = inflated_clearance(px.ravel(), py.ravel(), config.rec_point_times_s, field_h)
            ok_inf = ok_inf & (rc >= floor_inf - 1e-9).all(axis=0).reshape(n_r, -1)[:, 1:].all(axis=1)
            ok_true = ok_true & (rc + margins >= floor_true - 1e-9).all(axis=0).reshape(n_r, -1)[:, 1:].all(axis=1)
            distance = np.clip(rc.min(axis=0).reshape(n_r, -1)[:, 1:].min(axis=1), 0.0, config.distance_saturation_m)
        else:
            distance = np.full(n_r, config.distance_saturation_m)
        rules = np.ones(px.shape, dtype=bool)
        if sep_limit is not None:
            t = config.rec_point_times_s.reshape(n_r, -1)
            rules &= (px - other.x_m - other.vx_m_s * t) ** 2 + (py - other.y_m - other.vy_m_s * t) ** 2 >= sep_limit ** 2
        fence = config.fence_m
        if fence is not None:
            here = min(pose.x_m - fence[0], fence[2] - pose.x_m, pose.y_m - fence[1], fence[3] - pose.y_m)
            inside = np.minimum(np.minimum(px - fence[0], fence[2] - px), np.minimum(py - fence[1], fence[3] - py))
            rules &= inside >= min(here, 0.0) - 1e-9
        rules = rules[:, 1:].all(axis=1)
        for legal, how in ((ok_inf & rules, "recovering"), (None, None), (ok_true & rules, "recovering on the margin")):
            if legal is None:  # between the two recoveries: a hover that stays clear is the better wait
                if hover_inf[-1]:
                    return NoLegalRollout(f"{reason}; holding: no heading has a legal rollout")
                continue
            if not legal.any():
                continue
            scores = heading_scores(pts, pose.heading_rad + config.rec_final_dheading_rad, goals)
            sight = _sightline(pose, other, snapshot, config, pts[:, -1, 0], pts[:, -1, 1])
            total = _evaluate(config, legal, scores, distance, sight)
            i = int(total.argmax())
            turn = float(config.rec_turn_rad[i])
            yaw_rate = max(-config.max_yaw_rate_rad_s, min(config.max_yaw_rate_rad_s, turn / dt))
            command = Command(yaw_rate_rad_s=yaw_rate, speed_m_s=0.0, heading_score=float(scores[i]),
                              distance_score=float(distance[i]),
                              sightline_score=0.0 if sight is None else float(sight[i]),
                              eval_score=float(total[i]), legal_count=int(np.count_nonzero(legal)))
            return NoLegalRollout(f"{reason}; {how}: yaw {math.degrees(turn):+.0f} deg in place", recovery=command)
    elif hover_inf[-1]:
        return NoLegalRollout(reason)

    # Hovering will be hit and no heading helps: fly what stays clear of the true footprints longest.
    ok_pts = np.ones((config.samples, steps + 1), dtype=bool)
    for rule, ok in ok_by_rule.items():
        if rule != "obstacle":
            ok_pts &= ok
    if clear is not None:
        true_clear = clear + np.concatenate([near.circle_margin_m, near.poly_margin_m])[:, None]
        ok_pts &= (true_clear >= np.minimum(true_clear[:, 0:1], 0.0) - 1e-9).all(axis=0).reshape(ok_pts.shape)
    # legal steps flown; a rollout clear for the whole horizon outlasts any hover
    lasts = np.where(ok_pts[:, 1:].all(axis=1), hover_steps + 1, np.argmin(ok_pts[:, 1:], axis=1))
    hold_lasts = hover_steps if hover_true[-1] else int(np.argmin(hover_true[1:]))
    best_last = int(lasts.max())
    if best_last <= hold_lasts:
        return NoLegalRollout(f"{reason}; holding: nothing lasts longer than hovering ({hold_lasts * dt:g} s)")
    i = int(np.argmax(np.where(lasts == best_last, heading, -np.inf)))
    escape = _command(config, i, heading, np.zeros(config.samples), None, 0.0, 0)
    clear_for = "the horizon" if best_last > hover_steps else f"{min(best_last, steps) * dt:g} s"
    return NoLegalRollout(f"{reason}; escaping: clear for {clear_for}, hovering for {hold_lasts * dt:g} s", escape)


def _rotation(heading_rad: float) -> np.ndarray:
    """Right-multiplying (N, 2) body points by this turns them to ``heading_rad``."""
    c, s = math.cos(heading_rad), math.sin(heading_rad)
    return np.array([[c, s], [-s, c]])


def _sightline(pose: Pose, other: OtherUav | None, snapshot: ObstacleSnapshot, config: DwaConfig,
               ex: np.ndarray, ey: np.ndarray) -> np.ndarray | None:
    """S (capped) for prediction points (ex, ey), or None when the term is off: no other UAV,
    w_s = 0, or the other UAV has arrived (a parked UAV is no one to hide from, and a term that
    is non-zero for few candidates would outbid the heading critic under sum normalisation)."""
    if other is None or other.arrived or config.w_s <= 0 or not snapshot.count:
        return None
    t_p = config.horizon_s
    q = (other.x_m + other.vx_m_s * t_p, other.y_m + other.vy_m_s * t_p)
    # Sight lines run from somewhere within reach of the pose to q: skip obstacles far from both.
    keep, kept = snapshot.near_mask(pose.x_m, pose.y_m, config.reach_m, t_p, to_xy=q)
    if not kept:
        return None
    return np.minimum(config.sightline_cap_m,
                      _sightline_scores(ex, ey, q, t_p, snapshot, None if kept == len(keep) else keep))


def _commit_turn(pose: Pose, goals: LocalGoals, legal: np.ndarray, config: DwaConfig) -> np.ndarray:
    """Turn-around rule: with the goal more than ``turnaround_deg`` off the nose, only turns
    toward the goal's side (or straight on) stay candidates.

    With p long enough for a U-turn (the paper's formula), a goal behind the vehicle is matched
    at the prediction point equally well by turning left or right. Which side wins then flips
    with sample quantisation from one tick to the next, and the vehicle chatters between the
    two U-turns while flying away from its goal (nav2 DWB's OscillationCritic exists for the
    same reason). The side of the goal as seen from the current pose is a stable choice: turning
    toward it only shrinks the angle. It is a preference, not a safety rule: if it would leave
    no legal rollout, it is dropped.
    """
    gx, gy = goals.nodes_xy[0]
    error = (math.atan2(gy - pose.y_m, gx - pose.x_m) - pose.heading_rad + math.pi) % (2.0 * math.pi) - math.pi
    if abs(error) <= math.radians(config.turnaround_deg):
        return legal
    toward = legal & (config.yaw_rates_rad_s * error >= 0.0)
    return toward if toward.any() else legal


def _evaluate(config: DwaConfig, legal: np.ndarray, heading: np.ndarray, distance: np.ndarray,
              sightline: np.ndarray | None, everyone: bool | None = None) -> np.ndarray:
    """Eval = w_h H + w_d D + w_s S, each critic normalised by its sum over the legal candidates
    (Fox et al. 1997; a critic that is zero for all of them contributes nothing); -inf where
    illegal. ``everyone``: whether every candidate is legal, if the caller knows. Term by term
    on (S,) rows: this runs every tick."""
    if everyone is None:
        everyone = bool(legal.all())
    total = None
    for weight, critic in ((config.w_h, heading), (config.w_d, distance), (config.w_s, sightline)):
        if critic is None or weight == 0.0:
            continue
        if critic is config.saturated_m:  # nothing within reach: the same for every candidate
            norm = config.saturated_sums[len(critic) if everyone else int(np.count_nonzero(legal))]
            if norm > 0.0:
                term = config.distance_saturation_m * (weight / norm)
                total = np.full(len(critic), term) if total is None else total.__iadd__(term)
            continue
        norm = float(critic.sum() if everyone else critic[legal].sum())
        if norm > 0.0:
            term = critic * (weight / norm)
            if total is None:
                total = term
            else:
                total += term
    if total is None:
        total = np.zeros(len(heading))
    if not everyone:
        total[~legal] = -np.inf
    return total
