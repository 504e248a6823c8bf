"""SPEC §2 scoring on hand-made tracks: violations between samples, arrival, bounds, sight metrics."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from uav_model.mission import parse_mission
from companion.planning.metrics import Track, TruthGeometry, summarize, until_last_arrival

ONE_DISK = """
area: {x_min_m: 0, y_min_m: 0, x_max_m: 1000, y_max_m: 1000, geofence_margin_m: 100}
stations: {A: [0, 500], B: [1000, 500]}
obstacles:
  - {id: d, shape: circle, center: [500, 500], radius_m: 100}
vehicles:
  - {name: a, start: A, goal: B}
  - {name: b, start: B, goal: A}
safety: {min_separation_m: 50, arrival_radius_m: 20, time_limit_s: 500}
"""
M = parse_mission(ONE_DISK, "one_disk")


def line(t0, t1, p0, p1, dt=1.0) -> Track:
    t = np.arange(t0, t1 + 1e-9, dt)
    s = (t - t0) / (t1 - t0)
    return Track(t, p0[0] + s * (p1[0] - p0[0]), p0[1] + s * (p1[1] - p0[1]))


def detour(north: bool) -> Track:
    """A -> around the disk at 150 m -> B (or the reverse for south), 10 m/s."""
    y = 650.0 if north else 350.0
    pts = np.array([[0, 500], [350, y], [650, y], [1000, 500]] if north else
                   [[1000, 500], [650, y], [350, y], [0, 500]], dtype=float)
    seg = np.hypot(*np.diff(pts, axis=0).T)
    s = np.arange(0.0, seg.sum() + 1e-9, 5.0)
    s = np.append(s, seg.sum()) if s[-1] < seg.sum() else s
    cum = np.concatenate([[0], np.cumsum(seg)])
    x = np.interp(s, cum, pts[:, 0])
    yy = np.interp(s, cum, pts[:, 1])
    return Track(s / 10.0, x, yy)


def test_track_validates_its_arrays():
    with pytest.raises(ValueError):
        Track([0.0, 1.0], [0.0], [0.0, 1.0])
    with pytest.raises(ValueError):
        Track([0.0, 0.0], [0.0, 1.0], [0.0, 1.0])


def test_clean_run_succeeds_with_every_metric():
    s = summarize(M, {"a": detour(True), "b": detour(False)}, planner_ms={"a": [0.2, 0.4], "b": [0.3]})
    assert s.success and s.reason is None
    a = s.vehicles["a"]
    to_arrival = 2 * math.hypot(350, 150) + 300 - 20.0  # counted until inside the arrival radius
    assert a.arrived and a.path_length_m == pytest.approx(to_arrival, abs=5.0)
    assert a.flight_time_s == pytest.approx(a.path_length_m / 10.0, abs=0.5)  # sampled every 0.5 s
    assert a.arrival_t_s == a.flight_time_s
    assert a.min_obstacle_clearance_m == pytest.approx(50.0)  # the 300 m leg 150 m from the centre
    assert a.planner_ms_per_tick == pytest.approx(0.3)
    assert s.planner_ms_per_tick == pytest.approx(0.3)
    # Opposite sides of the disk: the sight line crosses it at the moment of closest approach.
    assert s.crossing_occluded is True and s.success_strict
    assert 0.0 < s.los_blocked_fraction <= 1.0
    assert s.min_separation_m > 250.0


def test_lower_bound_is_reported_with_the_ratio():
    s = summarize(M, {"a": detour(True), "b": detour(False)}, lower_bounds_s={"a": 100.0, "b": 100.0})
    assert s.vehicles["a"].lower_bound_s == 100.0
    assert s.vehicles["a"].ratio == pytest.approx(s.vehicles["a"].flight_time_s / 100.0)


def test_collision_between_samples_is_detected():
    # 250 m steps: the samples sit either side of the disk, the segment goes through it.
    a = Track([0.0, 25.0, 50.0, 75.0, 100.0], [0.0, 250.0, 750.0, 900.0, 1000.0], [500.0] * 5)
    geometry = TruthGeometry(M.world)
    samples_clear = np.hypot(a.x_m - 500.0, a.y_m - 500.0).min() - 100.0
    assert samples_clear > 100.0
    s = summarize(M, {"a": a, "b": detour(False)}, geometry=geometry)
    assert not s.success and s.reason == "collision" and s.failure_t_s == 50.0
    assert s.vehicles["a"].min_obstacle_clearance_m == 0.0


def test_moving_obstacle_running_into_a_hovering_vehicle_is_a_collision():
    m = parse_mission(ONE_DISK.replace(
        "  - {id: d, shape: circle, center: [500, 500], radius_m: 100}",
        "  - {id: d, shape: rectangle, center: [500, 900], width_m: 40, height_m: 40,\n"
        "     motion: {type: shuttle, to: [500, 100], speed_m_s: 10}}"), "moving")
    hover = Track([0.0, 60.0], [500.0, 500.0], [500.0, 500.0])  # one long sample interval
    s = summarize(m, {"a": hover, "b": detour(False)})
    assert s.reason == "collision"


def test_separation_violated_between_samples_is_detected():
    # Head-on along y = 800, sampled so that they are 200 m apart at both samples around the pass.
    a = line(0.0, 100.0, (0.0, 800.0), (1000.0, 800.0), dt=10.0)
    b = line(0.0, 100.0, (1000.0, 810.0), (0.0, 810.0), dt=10.0)
    assert np.hypot(a.x_m - b.x_m, a.y_m - b.y_m).min() >= 10.0
    s = summarize(M, {"a": a, "b": b})
    assert s.min_separation_m == pytest.approx(10.0)
    assert s.reason == "separation" and not s.success


def test_geofence_and_timeout_reasons():
    out = Track([0.0, 10.0, 20.0], [0.0, -150.0, 0.0], [500.0, 500.0, 500.0])
    assert summarize(M, {"a": out, "b": detour(False)}).reason == "geofence"
    slow = line(0.0, 500.0, (0.0, 900.0), (600.0, 900.0), dt=5.0)
    s = summarize(M, {"a": slow, "b": detour(False)})
    assert s.reason == "timeout" and not s.vehicles["a"].arrived and s.vehicles["b"].arrived
    s = summarize(M, {"a": line(0.0, 50.0, (0.0, 900.0), (200.0, 900.0)), "b": detour(False)})
    assert s.reason == "incomplete"
    s = summarize(M, {"a": detour(True), "b": detour(False)}, failure="link_lost", failure_t_s=3.0)
    assert s.reason == "link_lost" and not s.success


def test_earliest_violation_names_the_failure():
    a = Track([0.0, 10.0, 20.0, 30.0], [0.0, 0.0, 500.0, 500.0], [500.0, -150.0, -150.0, 500.0])
    s = summarize(M, {"a": a, "b": detour(False)})
    assert s.reason == "geofence" and s.failure_t_s == 10.0


def test_tracks_with_different_sample_times_are_merged():
    a = detour(True)
    b_dense = detour(False)
    b = Track(b_dense.t_s[::3] + 0.25, b_dense.x_m[::3], b_dense.y_m[::3])  # offset, sparser clock
    s = summarize(M, {"a": a, "b": b})
    assert s.success and s.min_separation_m > 250.0


def keep(track: Track, mask: np.ndarray) -> Track:
    return Track(track.t_s[mask], track.x_m[mask], track.y_m[mask])


def test_the_blocked_fraction_is_of_time_not_of_samples():
    # A loaded companion misses positions in bursts. The same flight, sampled densely where the
    # line is blocked and sparsely elsewhere, is blocked for the same share of its time.
    a = line(0.0, 100.0, (0.0, 800.0), (1000.0, 800.0), dt=0.5)  # north of the disk, west to east
    b = line(0.0, 100.0, (500.0, 200.0), (500.0, 200.0), dt=0.5)  # parked south of it
    even = summarize(M, {"a": a, "b": b}).los_blocked_fraction
    assert 0.1 < even < 0.5
    geometry = TruthGeometry(M.world)
    blocked = geometry.sight_blocked(a.x_m, a.y_m, b.x_m, b.y_m, a.t_s)
    assert np.array_equal(a.t_s, b.t_s)
    # every fourth sample where the line is open, every sample where it is blocked, ends kept
    thin = blocked | (np.arange(len(a)) % 4 == 0)
    thin[[0, -1]] = True
    uneven = summarize(M, {"a": keep(a, thin), "b": keep(b, thin)})
    assert np.mean(blocked[thin]) > even + 0.1  # counted per sample, the dense part would weigh more
    assert uneven.los_blocked_fraction == pytest.approx(even, abs=0.03)


def test_same_side_crossing_is_not_occluded_and_not_strict():
    a = line(0.0, 100.0, (0.0, 800.0), (1000.0, 800.0), dt=1.0)
    b = line(0.0, 100.0, (1000.0, 900.0), (0.0, 900.0), dt=1.0)
    # Stations are elsewhere, so neither arrives; the sight metrics still come out.
    s = summarize(M, {"a": a, "b": b})
    assert s.crossing_occluded is False and not s.success_strict
    assert s.los_blocked_fraction == 0.0


def test_summary_dict_has_the_issue_keys_and_is_json():
    s = summarize(M, {"a": detour(True), "b": detour(False)}, planner_ms={"a": [0.2], "b": [0.3]})
    d = s.summary_dict()
    json.dumps(d)
    for key in ("success", "success_strict", "reason", "vehicles", "min_separation_m",
                "los_blocked_fraction", "crossing_occluded", "planner_ms_per_tick"):
        assert key in d
    for key in ("flight_time_s", "path_length_m", "lower_bound_s", "arrived", "min_obstacle_clearance_m",
                "nodes_raw", "nodes_sparse"):
        assert key in d["vehicles"]["a"]


def _concat(*tracks: Track) -> Track:
    return Track(np.concatenate([t.t_s for t in tracks]), np.concatenate([t.x_m for t in tracks]),
                 np.concatenate([t.y_m for t in tracks]))


def test_what_a_vehicle_flies_after_its_arrival_counts_until_the_last_arrival():
    # a arrives at B (t ~ 104, around the disk to the north) and brakes 45 m on past it, toward b,
    # which comes down from the north and turns for A, arriving at t ~ 199; a lands further on,
    # after that last arrival.
    a = _concat(detour(north=True), line(107.0, 116.0, (1001.0, 510.0), (1010.0, 545.0)),
                line(201.0, 210.0, (1011.0, 546.0), (1020.0, 600.0)))
    b = _concat(line(0.0, 107.0, (1010.0, 900.0), (1010.0, 560.0)),
                line(108.0, 150.0, (1005.0, 560.0), (500.0, 700.0)), line(151.0, 200.0, (495.0, 700.0), (0.0, 505.0)))
    cut = until_last_arrival(M, {"a": a, "b": b})
    assert cut["a"].t_s[-1] == pytest.approx(201.0) and cut["b"].t_s[-1] == pytest.approx(199.0)  # first samples after
    s = summarize(M, cut)
    assert s.reason == "separation" and s.min_separation_m < 50.0  # a, braking past B, met b
    assert s.vehicles["a"].flight_time_s == pytest.approx(104.16, abs=0.01)  # the flight still ends at the arrival
    # Cut at a's own arrival instead, the meeting is never seen.
    assert summarize(M, {"a": detour(north=True), "b": b}).success


def test_a_vehicle_that_never_arrives_keeps_every_track_whole():
    a = line(0.0, 100.0, (0.0, 500.0), (500.0, 900.0))
    b = line(0.0, 100.0, (1000.0, 500.0), (0.0, 500.0))
    cut = until_last_arrival(M, {"a": a, "b": b})
    assert len(cut["a"]) == len(a) and len(cut["b"]) == len(b)
