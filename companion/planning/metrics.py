"""SPEC §2 in one place: success, failure reason and every reported metric, from flown tracks.

The input is plain :class:`Track` arrays (time, x, y in ENU metres) per vehicle, so the headless
runner, the live companion (from telemetry) and the pytest harness all score a flight with the
same code. Nothing here knows how the tracks were produced.

Checks are on the continuous path between samples, not only at the samples:

- obstacles: each step's segment against the TRUE footprints, moving ones at their true motion
  (the segment is taken in the obstacle's frame, which is exact while the obstacle moves on a
  straight line during the step);
- separation: the two vehicles move linearly between common samples, so the closest approach
  on each interval is a point-to-segment distance of the relative motion;
- geofence: the fence is a box, so a segment is inside exactly when both ends are.

Tracks of different vehicles may have different sample times (telemetry); they are merged on the
union of their times, a vehicle holding its first / last position outside its own track.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import TYPE_CHECKING, Any

import numpy as np

from companion.planning.bounds import lower_bound_s
from companion.planning.errors import PlanningError
from companion.planning.truth import TruthGeometry, inside_fence, pair_min_distance

if TYPE_CHECKING:
    from uav_model.mission import Mission



class FailureReason(StrEnum):
    """Why a run failed (SPEC §2). The value is the string summary.json and runs.csv show."""

    COLLISION = "collision"  # a vehicle touched a true obstacle footprint
    SEPARATION = "separation"  # two vehicles came closer than the minimum separation
    GEOFENCE = "geofence"  # a vehicle left the geofence (or the autopilot reported a breach)
    TIMEOUT = "timeout"  # the time limit came before every vehicle arrived
    INCOMPLETE = "incomplete"  # the flight ended before the time limit with a vehicle not arrived
    NO_PATH = "no_path"  # an A* variant found no route
    NO_SCENARIO = "no_scenario"  # the bench's generator could not make the scenario
    ERROR = "error"  # the run raised (a bug, reported as a row)
    LINK_LOST = "link_lost"  # live: telemetry or offboard control lost for too long
    LINK_CONFLICT = "link_conflict"  # live: a second system commands the vehicle
    LINK_IDENTITY = "link_identity"  # live: another system answers with the vehicle's id
    COMMAND_REFUSED = "command_refused"  # live: the autopilot refused a command
    UPLOAD_FAILED = "upload_failed"  # live: a mission or fence upload failed
    NOT_READY = "not_ready"  # live: health checks did not pass in time
    DISARMED = "disarmed"  # live: disarmed during take-off
    ABORTED = "aborted"  # live: another vehicle failed first
    OVERRIDE = "override"  # live: the pilot changed the mode; the companion stood down
    FAILSAFE = "failsafe"  # live: an autopilot failsafe the flight did not recover from
    INTERRUPTED = "interrupted"  # live: stopped by the operator


UNSAFE_REASONS = (FailureReason.COLLISION, FailureReason.SEPARATION, FailureReason.GEOFENCE)  # worst first


@dataclass(frozen=True, eq=False)
class Track:
    """One vehicle's flown path: strictly increasing sim times and ENU positions."""

    t_s: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray

    def __post_init__(self) -> None:
        arrays = [np.asarray(a, dtype=float).ravel() for a in (self.t_s, self.x_m, self.y_m)]
        if not (len(arrays[0]) == len(arrays[1]) == len(arrays[2]) >= 1):
            raise ValueError("a track needs t_s, x_m, y_m of the same non-zero length")
        if np.any(np.diff(arrays[0]) <= 0):
            raise ValueError("track times must be strictly increasing")
        for name, a in zip(("t_s", "x_m", "y_m"), arrays):
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    def __len__(self) -> int:
        return len(self.t_s)

    def at(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions at ``t_s``; held at the first / last sample outside the track."""
        return np.interp(t_s, self.t_s, self.x_m), np.interp(t_s, self.t_s, self.y_m)


@dataclass(frozen=True, slots=True)
class VehicleMetrics:
    name: str
    arrived: bool
    flight_time_s: float  # to arrival, or the whole track when it never arrived
    path_length_m: float
    lower_bound_s: float | None
    ratio: float | None  # flight time over the lower bound
    min_obstacle_clearance_m: float  # to the true footprints
    nodes_raw: int | None
    nodes_sparse: int | None
    planner_ms_per_tick: float | None
    planner_ms_max: float | None
    arrival_t_s: float | None


@dataclass(frozen=True, slots=True)
class PlannerCounts:
    """How often one vehicle's planner left plain tracking in a flight (headless runs)."""

    no_rollout_ticks: int  # ticks with no legal rollout: the vehicle hovered or yawed in place
    escape_ticks: int  # ticks flown on the escape fallback
    recovery_ticks: int  # ticks flown on a recovery (spin, hover) after no legal rollout
    stall_detours: int  # new routes planned after a stall (no progress for replan_after_s)
    timed_replans: int  # in-flight re-plans of the vehicle's timed route (timed variants)


@dataclass(frozen=True, slots=True)
class ScheduleRecord:
    """The coordination a flight ran under: the mission's settings and the plan's departure hold."""

    hold_s_max: float  # coordination.hold_s_max: how long the first vehicle may hold at its station
    forecast: str  # coordination.forecast: what the lower vehicles were planned against
    departure_hold_s: float | None  # the first vehicle's hold in the flown plan; None: no timed plan


@dataclass(frozen=True)
class RunSummary:
    success: bool
    success_strict: bool
    reason: FailureReason | None  # None on success
    failure_t_s: float | None
    vehicles: dict[str, VehicleMetrics]
    min_separation_m: float | None
    los_blocked_fraction: float | None
    crossing_occluded: bool | None
    planner_ms_per_tick: float | None
    duration_s: float
    pairs: dict[str, "PairMetrics"] = field(default_factory=dict)  # every pair, higher priority first
    sight_pairs: tuple[str, ...] = ()  # the keys of ``pairs`` whose sight line is scored (Mission.sight_pairs)
    planner: dict[str, PlannerCounts] = field(default_factory=dict)  # per vehicle (headless runs)
    schedule: ScheduleRecord | None = None  # headless runs

    @property
    def totals(self) -> PlannerCounts | None:
        """The planner counts summed over the vehicles (None without any)."""
        if not self.planner:
            return None
        return PlannerCounts(*(sum(getattr(c, k) for c in self.planner.values()) for k in PlannerCounts.__slots__))

    def summary_dict(self) -> dict[str, Any]:
        """The summary.json of ``companion simulate`` / ``run`` (JSON-ready)."""
        out: dict[str, Any] = {
            "success": self.success,
            "success_strict": self.success_strict,
            "reason": self.reason,
            "failure_t_s": self.failure_t_s,
            "duration_s": self.duration_s,
            "vehicles": {name: {k: getattr(v, k) for k in VehicleMetrics.__slots__ if k != "name"}
                         for name, v in self.vehicles.items()},
            "min_separation_m": self.min_separation_m,
            "los_blocked_fraction": self.los_blocked_fraction,
            "crossing_occluded": self.crossing_occluded,
            "planner_ms_per_tick": self.planner_ms_per_tick,
            "pairs": {name: {k: getattr(p, k) for k in PairMetrics.__slots__} for name, p in self.pairs.items()},
            "sight_pairs": list(self.sight_pairs),
        }
        if self.planner:
            out.update({f"planner_{k}": {n: getattr(c, k) for n, c in self.planner.items()}
                        for k in PlannerCounts.__slots__})
        if self.schedule is not None:
            out["schedule"] = {k: getattr(self.schedule, k) for k in ScheduleRecord.__slots__}
        return _json_ready(out)


def _json_ready(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_ready(v) for v in value]
    if isinstance(value, (np.bool_, bool)):
        return bool(value)
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        v = float(value)
        return round(v, 6) if math.isfinite(v) else None
    return value


def arrival(track: Track, goal_xy: tuple[float, float], radius_m: float) -> tuple[float | None, int, float]:
    """When the track first enters the arrival disc, checked along each step's segment.

    Returns (time, step index, fraction of that step); the time is interpolated inside the step,
    so sparse telemetry (a GCS stream at 2 s of sim time) and the 0.5 s headless steps score the
    same flight alike. (None, -1, 0.0) when it never arrives.
    """
    gx, gy = goal_xy
    x, y, t = track.x_m, track.y_m, track.t_s
    if math.hypot(x[0] - gx, y[0] - gy) <= radius_m:
        return float(t[0]), 0, 0.0
    if len(track) < 2:
        return None, -1, 0.0
    px, py = x[:-1] - gx, y[:-1] - gy
    dx, dy = np.diff(x), np.diff(y)
    a = dx * dx + dy * dy
    b = 2.0 * (px * dx + py * dy)
    c = px * px + py * py - radius_m * radius_m
    disc = b * b - 4.0 * a * c
    with np.errstate(divide="ignore", invalid="ignore"):
        s_in = (-b - np.sqrt(np.maximum(disc, 0.0))) / (2.0 * a)
    s_in = np.where(c <= 0.0, 0.0, s_in)  # a step that starts inside (only possible at index 0)
    hit = np.flatnonzero((a > 0) & (disc >= 0.0) & (s_in >= 0.0) & (s_in <= 1.0))
    if not hit.size:
        return None, -1, 0.0
    i = int(hit[0])
    s = float(s_in[i])
    return float(t[i] + s * (t[i + 1] - t[i])), i, s


def summarize(mission: "Mission", tracks: Mapping[str, Track], *,
              routes: Mapping[str, Any] | None = None,
              planner_ms: Mapping[str, Sequence[float]] | None = None,
              failure: FailureReason | str | None = None, failure_t_s: float | None = None,
              lower_bounds_s: Mapping[str, float] | None = None,
              geometry: TruthGeometry | None = None) -> RunSummary:
    """Score a flight (SPEC §2).

    ``failure``: a reason found outside the tracks (``no_path``, ``link_lost``...), reported
    unless the tracks show an earlier violation. ``routes`` (name -> Route) supplies the node
    counts; ``lower_bounds_s`` overrides the bound per vehicle (default: bounds.lower_bound_s).
    """
    world = mission.world
    geometry = geometry or TruthGeometry(world)
    safety = mission.safety
    names = [v.name for v in mission.by_priority if v.name in tracks]
    events: list[tuple[float, int, FailureReason]] = []  # (time, severity, reason)

    per_vehicle: dict[str, VehicleMetrics] = {}
    for name in names:
        spec = mission.vehicle(name)
        tr = tracks[name]
        gx, gy = spec.goal_enu_m
        t_arrive, end, frac = arrival(tr, (gx, gy), safety.arrival_radius_m)
        arrived = t_arrive is not None and t_arrive <= safety.time_limit_s
        if not arrived:
            end, frac = len(tr) - 1, 0.0
        steps = np.hypot(np.diff(tr.x_m[:end + 2]), np.diff(tr.y_m[:end + 2]))
        if len(steps) > end:
            steps[end] *= frac  # only the part of the last step up to the arrival point
        clearance = geometry.segment_clearance_m(tr.x_m[:-1], tr.y_m[:-1], tr.x_m[1:], tr.y_m[1:],
                                                 tr.t_s[:-1], tr.t_s[1:]) if len(tr) > 1 else \
            geometry.segment_clearance_m(tr.x_m, tr.y_m, tr.x_m, tr.y_m, tr.t_s, tr.t_s)
        hit = np.flatnonzero(clearance <= 0.0)
        if hit.size:
            events.append((float(tr.t_s[min(hit[0] + 1, len(tr) - 1)]), 0, FailureReason.COLLISION))
        out = np.flatnonzero(~inside_fence(world, tr.x_m, tr.y_m))
        if out.size:
            events.append((float(tr.t_s[out[0]]), 2, FailureReason.GEOFENCE))
        flight = float((t_arrive if arrived else tr.t_s[-1]) - tr.t_s[0])
        if lower_bounds_s is not None and name in lower_bounds_s:
            bound = lower_bounds_s[name]
        else:
            bound = vehicle_lower_bound_s(mission, name)
        route = None if routes is None else routes.get(name)
        ms = None if planner_ms is None or not len(planner_ms.get(name, ())) else np.asarray(planner_ms[name])
        per_vehicle[name] = VehicleMetrics(
            name=name, arrived=arrived, flight_time_s=flight, path_length_m=float(steps.sum()),
            lower_bound_s=bound, ratio=(flight / bound if bound and arrived else None),
            min_obstacle_clearance_m=float(clearance.min()) if clearance.size else math.inf,
            nodes_raw=None if route is None else int(route.nodes_raw),
            nodes_sparse=None if route is None else int(route.nodes_sparse),
            planner_ms_per_tick=None if ms is None else float(ms.mean()),
            planner_ms_max=None if ms is None else float(ms.max()),
            arrival_t_s=float(t_arrive) if arrived else None,
        )

    t_all = np.unique(np.concatenate([tracks[n].t_s for n in names]))
    min_sep = los_fraction = occluded = None
    pairs: dict[str, PairMetrics] = {}
    sight: tuple[str, ...] = ()
    if len(names) >= 2:
        pairs, sep = _pair_metrics(geometry, names, {n: tracks[n].at(t_all) for n in names}, t_all)
        min_sep = float(sep.min())
        close = np.flatnonzero(sep < safety.min_separation_m)
        if close.size:
            events.append((float(t_all[min(close[0] + 1, len(t_all) - 1)]), 1, FailureReason.SEPARATION))
        # The headline sight metrics are the first assigned pair (by default the paper's pair, the
        # two vehicles first in priority); strict success needs every assigned pair occluded.
        sight = tuple(name for name in (pair_name(a, b) for a, b in mission.sight_pairs) if name in pairs)
        if sight:
            headline = pairs[sight[0]]
            los_fraction, occluded = headline.los_blocked_fraction, headline.crossing_occluded

    reason = None
    fail_t = None
    if events:
        fail_t, _, reason = min(events)
    elif failure is not None:
        reason, fail_t = FailureReason(failure), failure_t_s
    elif not all(v.arrived for v in per_vehicle.values()):
        reason = (FailureReason.TIMEOUT if float(t_all[-1]) >= safety.time_limit_s - 1e-9
                  else FailureReason.INCOMPLETE)
        fail_t = float(t_all[-1])
    success = reason is None and len(per_vehicle) == len(mission.vehicles)
    if reason is None and not success:
        reason = FailureReason.INCOMPLETE
    all_ms = [m for n in names if planner_ms and len(planner_ms.get(n, ())) for m in planner_ms[n]]
    return RunSummary(
        success=success, success_strict=bool(success and all(pairs[name].crossing_occluded for name in sight)),
        reason=reason, failure_t_s=fail_t, vehicles=per_vehicle, min_separation_m=min_sep,
        los_blocked_fraction=los_fraction, crossing_occluded=occluded,
        planner_ms_per_tick=float(np.mean(all_ms)) if all_ms else None,
        duration_s=float(t_all[-1] - t_all[0]), pairs=pairs, sight_pairs=sight,
    )


def pair_name(a: str, b: str) -> str:
    """A pair's key: the higher-priority vehicle first."""
    return f"{a}-{b}"


@dataclass(frozen=True, slots=True)
class PairMetrics:
    """Separation and sightline of one pair of vehicles over the whole flight."""

    min_separation_m: float
    los_blocked_fraction: float  # of the flight's time (its samples weighted by their intervals), the sight line crossed a true footprint
    crossing_occluded: bool  # the sight line was blocked at the pair's closest approach


def _pair_metrics(geometry: TruthGeometry, names: Sequence[str], xy: Mapping[str, tuple[np.ndarray, np.ndarray]],
                  t_all: np.ndarray) -> tuple[dict[str, PairMetrics], np.ndarray]:
    """Every pair (in priority order) on the merged times, and the fleet's closest approach per step."""
    pairs: dict[str, PairMetrics] = {}
    sep_steps = []
    weights = _sample_weights(t_all)
    total = None if weights is None else math.fsum(weights)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            (ax, ay), (bx, by) = xy[a], xy[b]
            if len(t_all) > 1:
                d = pair_min_distance(ax[:-1], ay[:-1], ax[1:], ay[1:], bx[:-1], by[:-1], bx[1:], by[1:])
            else:
                d = np.hypot(ax - bx, ay - by)
            sep_steps.append(d)
            blocked = geometry.sight_blocked(ax, ay, bx, by, t_all)
            pairs[pair_name(a, b)] = PairMetrics(
                min_separation_m=float(d.min()),
                los_blocked_fraction=float(blocked.mean()) if weights is None else math.fsum(weights[blocked]) / total,
                crossing_occluded=bool(blocked[int(np.argmin(np.hypot(ax - bx, ay - by)))]))
    return pairs, np.min(np.stack(sep_steps), axis=0)


def _sample_weights(t_s: np.ndarray) -> np.ndarray | None:
    """The time each sample stands for (the interval it starts; the last, the one before it), so
    that a share of the samples is a share of the flight's time; None when the samples are
    equally spaced (headless flights), where the plain mean is that share. A live run's samples
    are not: a loaded companion misses positions in bursts, and counted per sample the stretches
    it saw densely would weigh more than the flight gave them."""
    if len(t_s) < 3:
        return None
    dt = np.diff(t_s)
    if float(np.ptp(dt)) <= 1e-9 * float(dt.max()):
        return None
    return np.append(dt, dt[-1])


def until_last_arrival(mission: "Mission", tracks: Mapping[str, Track]) -> dict[str, Track]:
    """The tracks up to the last vehicle's arrival (the first sample at or after it), when every
    vehicle arrived: the mission's metrics end there. Up to then they keep what each vehicle flew
    after its own arrival (braking in HOLD, landing), so that separation and clearance are judged
    where it was; a vehicle that never arrived keeps its whole track, and so do the others."""
    radius = mission.safety.arrival_radius_m
    ends = [arrival(tr, mission.vehicle(n).goal_enu_m, radius)[0] for n, tr in tracks.items()]
    if not ends or any(t is None for t in ends):
        return dict(tracks)
    t_end = max(ends)
    out = {}
    for name, tr in tracks.items():
        n = min(int(np.searchsorted(tr.t_s, t_end, side="left")) + 1, len(tr))
        out[name] = Track(tr.t_s[:n], tr.x_m[:n], tr.y_m[:n])
    return out


def vehicle_lower_bound_s(mission: "Mission", name: str) -> float | None:
    """Vehicle ``name``'s lower bound on flight time (SPEC §2), or None when there is none
    (no static route exists). It depends on the geometry only, not on the planner variant: a
    caller scoring several variants of one mission computes it once and passes it to
    :func:`summarize` as ``lower_bounds_s``."""
    spec = mission.vehicle(name)
    try:
        return float(lower_bound_s(mission.world, spec.start_enu_m, spec.goal_enu_m, spec.speed_m_s))
    except PlanningError:
        return None
