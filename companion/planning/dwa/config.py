"""DwaConfig: the window, weights and rules of one vehicle's BDWA, with the fixed rollout shapes
precomputed once (see :mod:`.shapes`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np

from companion.planning.dwa.backend import DEFAULT, Backend
from companion.planning.dwa.shapes import homogeneous, lagged_rollouts, recovery_shapes
from companion.planning.dwa.speed import scores_at
from uav_model.plant.unicycle import body_rollouts

if TYPE_CHECKING:  # only for the builder's signature; the core takes plain values
    from uav_model.mission import PlannerSettings, SafetySettings, VehicleSpec


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
    ``yield_margin_m``: kept from a UAV that has right of way (``OtherUav.right_of_way``) on top
    of ``min_separation_m``: the lower-priority vehicle gives way first, which breaks the
    symmetric standoffs of several vehicles meeting.
    ``turnaround_deg``: see :func:`companion.planning.dwa.legality.commit_turn`; 180 disables the rule.
    ``fence_m``: the geofence box; rollout points must stay inside it (legality, like obstacles).
    ``speed_samples``: speeds sampled from ``min_speed_m_s`` (hover: 0) to cruise ``speed_m_s``,
    each with every yaw rate (|yaw rate| <= v_cruise / r at every speed): a (speeds x rates)
    grid of rollouts, speeds outer. 1 is the paper's window: cruise only, the yaw rates alone.
    ``w_v``: weight of the speed critic (:mod:`.speed`), read only with more than one speed.
    ``sightline_slope``: S is the paper's depth when the sight line is blocked and minus the
    sight segment's clearance to the nearest obstacle when it is open (:mod:`.sightline`).
    ``fixed_scale``: each critic divided by a fixed scale (H / 180, D / saturation, S / cap,
    V / 1) instead of the paper's sum over the candidates (:mod:`.evaluate`).
    ``backend``: the kernels every tick of this config runs (:mod:`.backend`): numba's compiled
    twins when numba is installed, else numpy's; the same commands either way.
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
    yield_margin_m: float = 15.0
    turnaround_deg: float = 90.0
    fence_m: tuple[float, float, float, float] | None = None  # keep-in box (x0, y0, x1, y1)
    recovery_samples: int = 11  # yaw-rate samples per heading in the spin recovery; 0 disables it
    speed_samples: int = 1
    min_speed_m_s: float = 0.0
    w_v: float = 0.0
    sightline_slope: bool = False
    fixed_scale: bool = False
    # How long the plant trails a command (s; uav_model.plant.TRACKING_LAG_S): commanded to hover
    # at cruise it carries on about this long along its heading, and a spin recovery gets going
    # this much after its yaw (see recovery.hover_check). 0: the plant flies the rollouts exactly.
    tracking_lag_s: float = 0.0
    backend: Backend = field(default=DEFAULT, repr=False)

    # S below is the number of rollouts: yaw_rate samples x speed_samples (speeds outer).
    count: int = field(init=False, repr=False)  # S
    yaw_rates_rad_s: np.ndarray = field(init=False, repr=False)  # (S,)
    speeds_m_s: np.ndarray = field(init=False, repr=False)  # (S,)
    times_s: np.ndarray = field(init=False, repr=False)  # (K + 1,) 0, dt, ..., p
    body_xy_m: np.ndarray = field(init=False, repr=False)  # (S, K + 1, 2) from the origin, heading +x
    final_dheading_rad: np.ndarray = field(init=False, repr=False)  # (S,) heading change at p
    point_times_s: np.ndarray = field(init=False, repr=False)  # (S * (K + 1),) times of body_xy_m's points
    # body_xy_m as homogeneous columns (3, S * (K + 1)): [x; y; 1]. One (2, 3) @ (3, N) product
    # places every rollout point (see placement), x and y each coming out contiguous.
    body_hom_m: np.ndarray = field(init=False, repr=False)
    end_hom_m: np.ndarray = field(init=False, repr=False)  # (3, S): the prediction points only
    # The rollouts whose points differ: with a hover speed every yaw rate hovers on the same
    # spot, so obstacle clearance is computed once for them. row_of (S,) maps each rollout to its
    # row among the G distinct ones (geo_hom_m (3, G * (K + 1)), geo_point_times_s); None: all differ.
    row_of: np.ndarray | None = field(init=False, repr=False)
    distinct_row: np.ndarray = field(init=False, repr=False)  # (S,) int64: row_of, or each rollout's own row
    end_points: np.ndarray = field(init=False, repr=False)  # (S,) each rollout's prediction point among the distinct
    geo_hom_m: np.ndarray = field(init=False, repr=False)
    geo_point_times_s: np.ndarray = field(init=False, repr=False)
    # Plain numbers and constant rows the tick reads, derived once (a property would recompute).
    steps: int = field(init=False, repr=False)  # K
    horizon_s: float = field(init=False, repr=False)  # K dt
    reach_m: float = field(init=False, repr=False)  # how far a rollout goes: v K dt
    all_legal: np.ndarray = field(init=False, repr=False)  # (S,) all True
    saturated_m: np.ndarray = field(init=False, repr=False)  # (S,) all distance_saturation_m
    # all_legal and saturated_m as writable copies, as the compiled choice reads every critic row
    # (one signature); it never writes them.
    choice_rows: tuple[np.ndarray, np.ndarray] = field(init=False, repr=False)
    saturated_sums: tuple[float, ...] = field(init=False, repr=False)  # [n]: numpy's sum of n of them
    saturated_sums_m: np.ndarray = field(init=False, repr=False)  # the same as an array (compiled choice)
    weights: np.ndarray = field(init=False, repr=False)  # (w_h, w_d, w_s, w_v)
    moving_rollouts: np.ndarray = field(init=False, repr=False)  # (S,) the rollouts that do not hover
    slowest_move_m_s: float = field(init=False, repr=False)  # the least speed of those (inf: none)
    # (S,) the speed critic toward cruise speed (:func:`.speed.speed_scores`); writable, as the
    # compiled choice's other critic rows (one signature), and never written.
    cruise_speed_scores: np.ndarray = field(init=False, repr=False)
    # What the compiled choice reads of the config, as one tuple (see evaluate_jit): rates, speeds,
    # final_dheading_rad, weights, saturation, saturated_sums_m, sightline_slope, fixed_scale, cap.
    choice_consts: tuple = field(init=False, repr=False)
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
        if self.speed_samples < 1 or not 0.0 <= self.min_speed_m_s <= self.speed_m_s:
            raise ValueError("DwaConfig needs speed_samples >= 1 and 0 <= min_speed_m_s <= speed_m_s")
        steps = max(1, round(self.prediction_time_s / self.dt_s))
        rates = (np.zeros(1) if self.samples == 1
                 else np.linspace(-self.max_yaw_rate_rad_s, self.max_yaw_rate_rad_s, self.samples))
        t = self.dt_s * np.arange(0, steps + 1)
        if self.speed_samples == 1:  # the paper's window: the plant's own unicycle at cruise speed
            w, v = rates, np.full(len(rates), self.speed_m_s)
            body, dheading = body_rollouts(self.speed_m_s, w, self.dt_s, steps)
        else:
            levels = np.linspace(self.min_speed_m_s, self.speed_m_s, self.speed_samples)
            w, v = np.tile(rates, len(levels)), np.repeat(levels, len(rates))
            body, dheading = body_rollouts(v, w, self.dt_s, steps)
        cruise = slice(len(w) - len(rates), len(w))  # the recovery spins, then flies at cruise speed
        rec = recovery_shapes(body[cruise], dheading[cruise, -1], t, self.max_yaw_rate_rad_s, self.dt_s,
                              self.recovery_samples)
        object.__setattr__(self, "count", len(w))
        distinct = np.arange(len(w))
        if self.speed_samples > 1 and self.min_speed_m_s == 0.0:  # one hover row stands for all
            distinct = distinct[len(rates) - 1:]
        row_of = None if len(distinct) == len(w) else np.maximum(np.arange(len(w)) - (len(rates) - 1), 0)
        object.__setattr__(self, "row_of", row_of)
        distinct_row = np.arange(len(w), dtype=np.int64) if row_of is None else row_of.astype(np.int64)
        distinct_row.setflags(write=False)
        object.__setattr__(self, "distinct_row", distinct_row)
        end_points = distinct_row * (steps + 1) + steps
        end_points.setflags(write=False)
        object.__setattr__(self, "end_points", end_points)
        object.__setattr__(self, "geo_hom_m", homogeneous(body[distinct].reshape(-1, 2)))
        geo_times = np.tile(t, len(distinct))
        geo_times.setflags(write=False)  # read-only as point_times_s: one compiled signature for either
        object.__setattr__(self, "geo_point_times_s", geo_times)
        for name, value in (("yaw_rates_rad_s", w), ("speeds_m_s", v), ("times_s", t), ("body_xy_m", body),
                            ("final_dheading_rad", dheading[:, -1].copy()), ("point_times_s", np.tile(t, len(w))),
                            ("body_hom_m", homogeneous(body.reshape(-1, 2))),
                            ("end_hom_m", homogeneous(body[:, -1])), *rec.items()):
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        for name, value in (("all_legal", np.ones(len(w), dtype=bool)),
                            ("saturated_m", np.full(len(w), self.distance_saturation_m))):
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        object.__setattr__(self, "choice_rows", (self.all_legal.copy(), self.saturated_m.copy()))
        object.__setattr__(self, "saturated_sums", tuple(float(self.saturated_m[:n].sum()) for n in range(len(w) + 1)))
        moving = self.speeds_m_s > 0.0
        object.__setattr__(self, "cruise_speed_scores", scores_at(self.speeds_m_s, self.speed_m_s, self.speed_m_s))
        object.__setattr__(self, "slowest_move_m_s", float(self.speeds_m_s[moving].min()) if moving.any() else np.inf)
        for name, value in (("saturated_sums_m", np.array(self.saturated_sums)), ("moving_rollouts", moving),
                            ("weights", np.array([self.w_h, self.w_d, self.w_s, self.w_v], dtype=float))):
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        object.__setattr__(self, "choice_consts", (
            self.yaw_rates_rad_s, self.speeds_m_s, self.final_dheading_rad, self.weights,
            float(self.distance_saturation_m), self.saturated_sums_m, bool(self.sightline_slope),
            bool(self.fixed_scale),
            float(self.sightline_cap_m)))
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
    def stop_drift_m(self) -> float:
        """How far the plant carries on along its heading after a hover command at cruise (the
        most it carries on)."""
        return self.tracking_lag_s * self.speed_m_s

    @cached_property
    def lagged_rest_hom_m(self) -> np.ndarray | None:
        """The rollouts as the lagging plant flies them from rest (:func:`.shapes.lagged_rollouts`),
        as body_hom_m's homogeneous columns; None when the plant flies them exactly. The plant's
        velocity lag is linear, so from a velocity v it flies these plus v times
        :attr:`lagged_drift_s` (:func:`.shapes.lagged_points`). Built on first use."""
        if self.tracking_lag_s <= 0.0:
            return None
        body = lagged_rollouts(self.speeds_m_s, self.yaw_rates_rad_s, 0.0, self.dt_s, self.steps,
                               self.tracking_lag_s)
        return homogeneous(body.reshape(-1, 2))

    @cached_property
    def lagged_drift_s(self) -> np.ndarray:
        """(S * (K + 1),) how far the lagging plant carries on per m/s it has, at each rollout point's time."""
        drift = lagged_rollouts(np.zeros(1), np.zeros(1), 1.0, self.dt_s, self.steps, max(self.tracking_lag_s, 1e-9))
        return np.tile(drift[0, :, 0], self.count)

    @property
    def spin_time_s(self) -> float:
        """The longest yaw in place the recovery may ask for (half a turn)."""
        return float(self.rec_delay_s.max()) if self.rec_delay_s.size else 0.0
