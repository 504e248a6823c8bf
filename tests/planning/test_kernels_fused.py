"""The compiled backend's fused kernels (``obstacle_rule`` and ``pick``) give bit for bit what the
numpy backend's rows give: the obstacle pass (clearances, the rule per point and per
rollout, the distance critic) on random worlds and rollouts, and the fused choice (heading
critic toward one target, choice, command) on random windows and critics; and the goal windows
the tracker now builds from views of its route hold what the constructor derives."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from companion.planning.dwa import DwaConfig, LocalGoals, ObstacleSnapshot
from companion.planning.dwa.backend import COMPILED, NUMPY
from companion.planning.dwa.legality import Rule, legal_rollouts
from tests.planning.test_kernels import choices, worlds

needs_numba = pytest.mark.skipif(COMPILED is None, reason="needs the fast extra (numba): pip install -e '.[fast]'")


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal to the last bit (the sign of zero included), of the same dtype and shape."""
    a, b = np.atleast_1d(a), np.atleast_1d(b)
    return a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a.view(np.uint8), b.view(np.uint8))


@needs_numba
@settings(max_examples=80, deadline=None)
@given(worlds(), st.integers(0, 2**31), st.sampled_from([1, 7, 31]), st.sampled_from([2, 5, 23]),
       st.floats(-250.0, 250.0), st.floats(-250.0, 250.0), st.floats(-3.2, 3.2), st.floats(20.0, 600.0),
       st.sampled_from([1, 4]))
def test_obstacle_pass_matches_numpy(snap: ObstacleSnapshot, seed: int, samples: int, steps: int, x: float, y: float,
                                     heading: float, reach: float, speeds: int) -> None:
    """Rollouts of a real window placed anywhere among the obstacles (inside some of them too),
    over the obstacles culling keeps (the compiled pass reads the snapshot through the mask, the
    numpy code the culled subset). A speed window's distinct rollouts (its hovers as one) with
    their own times, as a tick passes them."""
    config = DwaConfig(speed_m_s=10.0, max_yaw_rate_rad_s=0.3, samples=samples, dt_s=0.5,
                       prediction_time_s=0.5 * (steps - 1), w_h=1.0, w_d=1.0, w_s=1.0, sightline_cap_m=50.0,
                       distance_saturation_m=float(np.random.default_rng(seed).choice([0.0, 10.0, 30.0])),
                       speed_samples=speeds)
    hom, times = (config.body_hom_m, None) if config.row_of is None else (config.geo_hom_m, config.geo_point_times_s)
    assert (config.row_of is None) == (speeds == 1 or samples == 1)  # a speed window keeps one hover
    c, s = np.cos(heading), np.sin(heading)
    xy = np.array([[c, -s, x], [s, c, y]]) @ hom
    shape = (xy.shape[1] // (config.steps + 1), config.steps + 1)
    px, py = xy[0].reshape(shape), xy[1].reshape(shape)
    culled = COMPILED.cull(snap, x, y, reach, config.horizon_s)
    assume(culled.count)
    clear, ok, distance, legal = COMPILED.obstacle_rule(px, py, culled, config, times)
    ref_clear, ref_ok, ref_distance, ref_legal = NUMPY.obstacle_rule(px, py, NUMPY.cull(snap, x, y, reach,
                                                                                         config.horizon_s), config,
                                                                     times)
    assert ref_legal is None  # the numpy row leaves the rule per rollout to legal_rollouts
    ref_legal = legal_rollouts({Rule.OBSTACLE: ref_ok}, config)
    assert same_bits(ok, ref_ok) and same_bits(distance, ref_distance) and same_bits(legal, ref_legal)
    # The clearances: exact when returned; left out (None) only when some lie above the saturation.
    if clear is not None:
        assert same_bits(clear, ref_clear)
    else:
        assert (ref_clear > config.distance_saturation_m).any()


@needs_numba
@settings(max_examples=200, deadline=None)
@given(choices(), st.integers(0, 2**31), st.floats(-300.0, 300.0), st.floats(-300.0, 300.0), st.floats(-4.0, 4.0))
def test_fused_choice_matches_numpy(case, seed: int, tx: float, ty: float, heading_rad: float) -> None:
    """The same command, every field to the last bit, as the heading critic toward (tx, ty),
    the choice and command_for give with the numpy code (ties, nothing legal, all legal)."""
    config, critics, _ = case
    rng = np.random.default_rng(seed)
    ex, ey = rng.uniform(-300.0, 300.0, (2, config.count))
    ex[::5] = tx  # straight above or below the target, and on it
    ey[::7] = ty
    got = COMPILED.pick(config, critics, ex, ey, heading_rad, (tx, ty))
    reference = NUMPY.pick(config, critics, ex, ey, heading_rad, (tx, ty))
    assert got.legal_count == reference.legal_count
    for name in ("yaw_rate_rad_s", "speed_m_s", "heading_score", "distance_score", "sightline_score", "eval_score"):
        assert same_bits(np.float64(getattr(got, name)), np.float64(getattr(reference, name))), name
    assert type(got.legal_count) is int


@needs_numba
@settings(max_examples=200, deadline=None)
@given(st.integers(0, 2**31), st.integers(1, 40), st.sampled_from([0.0, -0.0, 7.5]), st.sampled_from([0.0, -0.0, -3.0]),
       st.floats(-4.0, 4.0))
def test_heading_toward_shared_prediction_points(seed: int, n: int, tx: float, ty: float, heading_rad: float) -> None:
    """Runs of rollouts sharing one prediction point (a speed window's hovers), some on the
    target's axes or on the target itself, with zeros of either sign: the compiled heading
    critic toward one target gives, rollout by rollout, numpy's bits."""
    rng = np.random.default_rng(seed)
    pool = np.array([tx, -tx, tx + 1e-13, 0.0, -0.0, 5.0, -5.0])
    ex, ey = rng.choice(pool, n), rng.choice(pool - tx + ty, n)
    runs = np.repeat(np.arange(n), rng.integers(1, 5, n))[:n]  # consecutive rollouts sharing a point
    ex, ey = ex[runs], ey[runs]
    final = heading_rad + rng.uniform(-1.5, 1.5, n)
    goals = LocalGoals.single((tx, ty))
    got = COMPILED.heading_from_ends(ex, ey, final, goals, (0.0, 0.0), None, None, True)
    reference = NUMPY.heading_from_ends(ex, ey, final, goals, (0.0, 0.0), None, None, True)
    assert same_bits(got, reference)


@needs_numba
@settings(max_examples=200, deadline=None)
@given(choices(), st.integers(0, 2**31), st.integers(1, 4), st.booleans(), st.floats(-4.0, 4.0))
def test_fused_goal_window_choice_matches_numpy(case, seed: int, n_goals: int, station: bool,
                                                heading_rad: float) -> None:
    """Over a goal window (some rollouts reaching goals, passing them, or arriving at the
    station), the compiled pick reads the distinct rollouts through the window's row map and
    gives the command, every field to the last bit, that the numpy heading critic over the
    spread rollouts, the choice and command_for give."""
    config, critics, _ = case
    rng = np.random.default_rng(seed)
    n_k = config.steps + 1
    rows = config.count if config.row_of is None else int(config.row_of.max()) + 1
    gx, gy = rng.uniform(-60.0, 60.0, (2, rows, n_k)).cumsum(axis=2)
    nodes = np.concatenate([gx[rng.integers(0, rows, n_goals), rng.integers(0, n_k, n_goals)][:, None],
                            gy[rng.integers(0, rows, n_goals), rng.integers(0, n_k, n_goals)][:, None]], axis=1)
    goals = LocalGoals(nodes, (0.0, 0.0), 30.0, 40.0, ends_at_station=station)
    row_of = np.arange(config.count) if config.row_of is None else config.row_of
    ex, ey = gx[row_of, -1], gy[row_of, -1]
    args = (config, critics, ex, ey, heading_rad, gx, gy, goals, 5.0)
    got, reference = COMPILED.pick_goals(*args), NUMPY.pick_goals(*args)
    assert got.legal_count == reference.legal_count
    for name in ("yaw_rate_rad_s", "speed_m_s", "heading_score", "distance_score", "sightline_score", "eval_score"):
        assert same_bits(np.float64(getattr(got, name)), np.float64(getattr(reference, name))), name


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 2**31), st.integers(2, 40), st.data())
def test_route_window_is_the_constructors(seed: int, n: int, data) -> None:
    """LocalGoals.along (the tracker's windows, their arrays views of the route) holds, to the
    last bit, what the constructor derives (the heading critic reads these arrays)."""
    nodes = np.random.default_rng(seed).uniform(-900.0, 900.0, (n, 2))
    i = data.draw(st.integers(1, n - 1))
    count = data.draw(st.integers(1, n - i))
    acceptance, station = data.draw(st.sampled_from([0.0, 10.0, 30.0])), data.draw(st.sampled_from([5.0, 20.0]))
    got = LocalGoals.along(nodes, i, count, acceptance, station)
    reference = LocalGoals(nodes[i:i + count], (float(nodes[i - 1, 0]), float(nodes[i - 1, 1])), acceptance, station,
                           ends_at_station=i + count == n)
    for name in ("nodes_xy", "prev_nodes_xy", "radius2_m2"):
        assert same_bits(getattr(got, name), getattr(reference, name)), name
    for name in ("prev_xy", "acceptance_radius_m", "station_radius_m", "ends_at_station", "first_xy"):
        assert getattr(got, name) == getattr(reference, name), name
