"""The tick's worst cases are bounded by culling, and culling changes no decision: the spin
recovery's and the hover check's culled measurements agree with measuring every point to every
obstacle, a tick among crowds of obstacles decides as it does without the ones out of reach, and
a vehicle boxed in holds where it is."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.planning.dwa import DwaConfig, NoLegalRollout, ObstacleSnapshot, Pose, plan_step
from companion.planning.dwa.backend import COMPILED, NUMPY
from companion.planning.dwa.geometry import inflated_clearance
from companion.planning.dwa.recovery import hover_check, spin_candidates

BACKENDS = [NUMPY] + ([COMPILED] if COMPILED is not None else [])


def config(lag_s: float = 2.0, speeds: int = 1, backend=NUMPY, **extra) -> DwaConfig:
    return DwaConfig(speed_m_s=10.0, max_yaw_rate_rad_s=0.35, samples=31, dt_s=0.5, prediction_time_s=11.0, w_h=0.37,
                     w_d=0.6, w_s=0.03, sightline_cap_m=50.0, tracking_lag_s=lag_s, speed_samples=speeds,
                     w_v=0.2 if speeds > 1 else 0.0, backend=backend, **extra)


def crowd(seed: int, count: int, inner_m: float = 12.0, outer_m: float = 160.0) -> ObstacleSnapshot:
    """``count`` circles (a fifth of them moving) and up to 5 polygons around the origin."""
    rng = np.random.default_rng(seed)
    radius, angle = rng.uniform(inner_m, outer_m, count), rng.uniform(-math.pi, math.pi, count)
    moving = rng.random(count) < 0.2
    circles = [(f"c{i}", float(radius[i] * math.cos(angle[i])), float(radius[i] * math.sin(angle[i])),
                float(rng.uniform(3.0, 15.0)), float(rng.uniform(0.0, 8.0)),
                *((float(rng.uniform(-4, 4)), float(rng.uniform(-4, 4))) if moving[i] else (0.0, 0.0)))
               for i in range(count)]
    polygons = []
    for i in range(int(rng.integers(0, 6))):
        n = int(rng.integers(3, 7))
        turn, size = np.sort(rng.uniform(0.0, 2.0 * math.pi, n)), rng.uniform(5.0, 25.0, n)
        centre = rng.uniform(-120.0, 120.0, 2)
        polygons.append((f"p{i}", np.c_[centre[0] + size * np.cos(turn), centre[1] + size * np.sin(turn)],
                         float(rng.uniform(0.0, 8.0)), *rng.uniform(-3.0, 3.0, 2) * (rng.random() < 0.3)))
    return ObstacleSnapshot.build(circles, polygons)


def every_point_spin_checks(pose: Pose, cfg: DwaConfig, snap: ObstacleSnapshot):
    """What the spin recovery's obstacle rule and distance critic are: every point of every
    recovery rollout measured to every obstacle within reach."""
    hover = hover_check(pose, (), snap, cfg)
    pts, ok_inf, ok_true, _ = spin_candidates(pose, cfg.__class__(**{**_fields(cfg), "backend": NUMPY}), hover)
    delay_k = np.rint((cfg.rec_delay_s + cfg.tracking_lag_s) / cfg.dt_s).astype(int)
    n_r = len(pts)
    rc = inflated_clearance(pts[..., 0].ravel(), pts[..., 1].ravel(), cfg.rec_point_times_s, hover.field)
    want_inf = hover.inflated[delay_k] & (rc >= hover.floor_inflated - 1e-9).all(axis=0).reshape(n_r, -1)[:, 1:].all(1)
    want_true = hover.true[delay_k] & (rc + hover.margins >= hover.floor_true - 1e-9).all(axis=0).reshape(
        n_r, -1)[:, 1:].all(1)
    distance = np.clip(rc.min(axis=0).reshape(n_r, -1)[:, 1:].min(axis=1), 0.0, cfg.distance_saturation_m)
    return want_inf, want_true, distance


def _fields(cfg: DwaConfig) -> dict:
    return {name: getattr(cfg, name) for name in cfg.__dataclass_fields__ if cfg.__dataclass_fields__[name].init}


@pytest.mark.parametrize("backend", BACKENDS, ids=lambda b: b.name)
@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**31), st.sampled_from([20, 80, 200]), st.sampled_from([0.0, 2.0]),
       st.floats(-math.pi, math.pi))
def test_culled_spin_checks_are_every_points(backend, seed: int, count: int, lag_s: float, heading: float) -> None:
    snap = crowd(seed, count)
    pose = Pose(0.0, 0.0, heading)
    cfg = config(lag_s, backend=backend)
    want_inf, want_true, want_distance = every_point_spin_checks(pose, cfg, snap)
    hover = hover_check(pose, (), snap, cfg)
    _, ok_inf, ok_true, distance = spin_candidates(pose, cfg, hover)
    assert np.array_equal(ok_inf, want_inf) and np.array_equal(ok_true, want_true)
    legal = ok_inf | ok_true
    assert np.array_equal(distance[legal].view(np.uint64), want_distance[legal].view(np.uint64))


@pytest.mark.parametrize("backend", BACKENDS, ids=lambda b: b.name)
@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**31), st.sampled_from([0.0, 2.0]), st.floats(-math.pi, math.pi))
def test_culled_hover_check_is_every_obstacles(backend, seed: int, lag_s: float, heading: float) -> None:
    """Obstacles close enough to touch the braking segment, some already around the pose."""
    snap = crowd(seed, 60, inner_m=0.0, outer_m=60.0)
    pose = Pose(0.0, 0.0, heading)
    got = hover_check(pose, (), snap, config(lag_s, backend=backend))
    cfg = config(lag_s)
    ahead = np.linspace(0.0, cfg.stop_drift_m, 1 + math.ceil(cfg.stop_drift_m / 2.0))
    t = cfg.dt_s * np.arange(got.steps + 1)
    hc = inflated_clearance(np.repeat(ahead * math.cos(heading), len(t)), np.repeat(ahead * math.sin(heading), len(t)),
                            np.tile(t, len(ahead)), got.field)
    if len(ahead) > 1:
        hc = np.concatenate([hc[:, 0:1], hc.reshape(len(hc), len(ahead), -1).min(axis=1)[:, 1:]], axis=1)
    floor_inf, floor_true = np.minimum(hc[:, 0:1], 0.0), np.minimum(hc[:, 0:1] + got.margins, 0.0)
    assert np.array_equal(got.floor_inflated, floor_inf) and np.array_equal(got.floor_true, floor_true)
    assert np.array_equal(got.inflated, np.logical_and.accumulate((hc >= floor_inf - 1e-9).all(axis=0)))
    assert np.array_equal(got.true, np.logical_and.accumulate((hc + got.margins >= floor_true - 1e-9).all(axis=0)))


@pytest.mark.parametrize("backend", BACKENDS, ids=lambda b: b.name)
@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31), st.sampled_from([30, 120, 200]), st.sampled_from([1, 4]), st.floats(-math.pi, math.pi))
def test_a_crowded_tick_decides_as_without_the_obstacles_out_of_reach(backend, seed: int, count: int, speeds: int,
                                                                       heading: float) -> None:
    """The same command, hold, recovery or escape, with 200 more obstacles just out of every
    rollout's reach (and of the spin recovery's), as without them. (No other UAV: obstacles
    anywhere along the sight line to it count.)"""
    cfg = config(speeds=speeds, backend=backend)
    near = crowd(seed, count)
    rng = np.random.default_rng(seed + 1)
    far_m = cfg.reach_m + cfg.distance_saturation_m + 20.0 + 15.0 + 8.0  # + the largest radius and margin
    angle, radius = rng.uniform(-math.pi, math.pi, 200), rng.uniform(far_m + 1.0, far_m + 400.0, 200)
    far = ObstacleSnapshot.build([(f"f{i}", float(r * math.cos(a)), float(r * math.sin(a)), 15.0, 8.0, 0.0, 0.0)
                                  for i, (a, r) in enumerate(zip(angle, radius))], [])
    pose, goal = Pose(0.0, 0.0, heading), (800.0, 300.0)
    alone = plan_step(pose, goal, None, near, cfg)
    crowded = plan_step(pose, goal, None, near.merged(far), cfg)
    assert repr(crowded) == repr(alone)


@pytest.mark.parametrize("backend", BACKENDS, ids=lambda b: b.name)
@pytest.mark.parametrize("lag_s", [0.0, 2.0])
def test_a_boxed_in_vehicle_holds_clear_of_every_obstacle(backend, lag_s: float) -> None:
    """A closed ring of 40 circles 30 m out and 160 beyond: no rollout and no spin-recovery
    heading is legal, the hover point is clear, so the vehicle holds where it is."""
    ring = [(f"r{i}", 30.0 * math.cos(a), 30.0 * math.sin(a), 4.0, 2.0, 0.0, 0.0)
            for i, a in enumerate(np.linspace(-math.pi, math.pi, 40, endpoint=False))]
    rng = np.random.default_rng(3)
    beyond = [(f"b{i}", r * math.cos(a), r * math.sin(a), 8.0, 2.0, 0.0, 0.0)
              for i, (r, a) in enumerate(zip(rng.uniform(60.0, 110.0, 160), rng.uniform(-math.pi, math.pi, 160)))]
    snap = ObstacleSnapshot.build(ring + beyond, [])
    result = plan_step(Pose(0.0, 0.0, 0.3), (900.0, 900.0), None, snap, config(lag_s, backend=backend))
    assert isinstance(result, NoLegalRollout)
    assert result.escape is None and result.recovery is None, result.reason
    assert "holding" in result.reason
    hover = inflated_clearance(np.zeros(1), np.zeros(1), np.zeros(1), snap)
    assert hover.min() > 0.0  # where it holds is clear of every inflated obstacle
