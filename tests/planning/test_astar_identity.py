"""The optimised A*, compiled or Python, returns exactly the oracle's paths (same cells, same order)
and the same refusals.

Every published result (ablation tables, reference mission) rests on these paths, so a speed-up
may not change one cell of one path. The oracle is the implementation at b4afd9b, frozen in
``astar_reference.py``.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import astar_reference
from companion.planning.astar import astar
from companion.planning.errors import NoPath
from companion.planning.grid import OccupancyGrid


pytestmark = pytest.mark.usefixtures("astar_search")  # every test on both searches


def outcome(fn, *args, **kwargs):
    """The path, or the error's type and message."""
    try:
        return fn(*args, **kwargs)
    except NoPath as exc:  # BudgetExceeded included
        return type(exc), str(exc)


def assert_same(grid: OccupancyGrid, start, goal, **kwargs) -> object:
    """Runs both with fresh (stateful) cancel callbacks; returns the shared outcome."""
    make_cancel = kwargs.pop("make_cancel", None)
    got = outcome(astar, grid, start, goal,
                  **kwargs, **({"cancel": make_cancel()} if make_cancel else {}))
    want = outcome(astar_reference.astar, grid, start, goal,
                   **kwargs, **({"cancel": make_cancel()} if make_cancel else {}))
    if isinstance(want, np.ndarray):
        assert isinstance(got, np.ndarray), f"oracle found a path, new code says {got}"
        assert got.shape == want.shape and np.array_equal(got, want), "paths differ"
    else:
        assert got == want
    return want


def cancel_after(calls: int):
    """A cancel callback that says stop on its ``calls``-th poll: both must poll at the same expansions."""
    count = [0]

    def cancel() -> bool:
        count[0] += 1
        return count[0] >= calls
    return cancel


def noise(rng: np.random.Generator, ny: int, nx: int, blocked: float) -> np.ndarray:
    return rng.random((ny, nx)) < blocked


def discs(rng: np.random.Generator, ny: int, nx: int, count: int) -> np.ndarray:
    yy, xx = np.mgrid[0:ny, 0:nx]
    occ = np.zeros((ny, nx), dtype=bool)
    for _ in range(count):
        cx, cy = rng.uniform(0, nx), rng.uniform(0, ny)
        r = rng.uniform(0.02, 0.12) * max(nx, ny)
        occ |= (xx - cx) ** 2 + (yy - cy) ** 2 < r * r
    return occ


def boxes(rng: np.random.Generator, ny: int, nx: int, count: int) -> np.ndarray:
    """Axis-aligned walls and rooms: long straight runs, many forced neighbours, ties galore."""
    occ = np.zeros((ny, nx), dtype=bool)
    for _ in range(count):
        x0, y0 = rng.integers(0, nx), rng.integers(0, ny)
        occ[y0:y0 + rng.integers(1, max(2, ny // 3)), x0:x0 + rng.integers(1, max(2, nx // 3))] = True
    return occ


def _bench_module():
    """benchmarks/bench_astar.py, whose grids this test must search exactly as the benchmark does."""
    path = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_astar.py"
    spec = importlib.util.spec_from_file_location("bench_astar", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def bench_grid(kind: str, seed: int, n: int = 1000) -> OccupancyGrid:
    """The benchmark's own draw (one source for the grids the docs quote)."""
    return _bench_module().random_grid(kind, seed, n)


MAPS = {
    "empty": lambda rng, ny, nx: np.zeros((ny, nx), dtype=bool),
    "noise5": lambda rng, ny, nx: noise(rng, ny, nx, 0.05),
    "noise10": lambda rng, ny, nx: noise(rng, ny, nx, 0.10),
    "noise20": lambda rng, ny, nx: noise(rng, ny, nx, 0.20),
    "noise30": lambda rng, ny, nx: noise(rng, ny, nx, 0.30),
    "noise45": lambda rng, ny, nx: noise(rng, ny, nx, 0.45),
    "discs": lambda rng, ny, nx: discs(rng, ny, nx, 12),
    "boxes": lambda rng, ny, nx: boxes(rng, ny, nx, 10),
}
SIZES = ((1, 1), (1, 9), (9, 1), (2, 2), (3, 5), (8, 8), (13, 7), (40, 40), (31, 97), (120, 80), (250, 250))


def random_point(rng: np.random.Generator, grid: OccupancyGrid, free_bias: float) -> tuple[float, float]:
    """Mostly a free cell (anywhere inside it); sometimes a blocked cell or a point off the grid."""
    ny, nx = grid.shape
    x0, y0, x1, y1 = grid.extent_m
    u = rng.random()
    free_cells = np.argwhere(~grid.occupied)
    if u < free_bias and len(free_cells):
        iy, ix = free_cells[rng.integers(len(free_cells))]
    elif u < 0.97:
        iy, ix = rng.integers(ny), rng.integers(nx)
    else:
        return float(rng.uniform(x0 - 5, x1 + 5)), float(y1 + rng.uniform(0.01, 3))
    return (float(grid.origin_m[0] + (ix + rng.random()) * grid.resolution_m),
            float(grid.origin_m[1] + (iy + rng.random()) * grid.resolution_m))


@pytest.mark.parametrize("kind", sorted(MAPS))
def test_same_paths_and_refusals_on_seeded_random_grids(kind):
    rng = np.random.default_rng(sum(map(ord, kind)))
    outcomes = {"path": 0, "refused": 0}
    for ny, nx in SIZES:
        for _ in range(3 if ny * nx > 5000 else 6):
            resolution_m = float(rng.choice([0.5, 1.0, 10.0]))
            grid = OccupancyGrid((float(rng.uniform(-50, 50)), float(rng.uniform(-50, 50))), resolution_m,
                                 MAPS[kind](rng, ny, nx))
            for _ in range(4):
                start, goal = random_point(rng, grid, 0.9), random_point(rng, grid, 0.9)
                heuristic = str(rng.choice(["octile", "euclidean"]))
                result = assert_same(grid, start, goal, heuristic=heuristic)
                outcomes["path" if isinstance(result, np.ndarray) else "refused"] += 1
    assert outcomes["path"] > 20, outcomes  # the comparison must have exercised real searches


@pytest.mark.parametrize("kind", ["noise10", "noise20", "discs", "boxes"])
def test_same_budget_and_cancel_behaviour(kind):
    rng = np.random.default_rng(7 + len(kind))
    budgets_hit = 0
    for _ in range(12):
        grid = OccupancyGrid((0.0, 0.0), 1.0, MAPS[kind](rng, 150, 150))
        start, goal = random_point(rng, grid, 1.0), random_point(rng, grid, 1.0)
        budget = int(rng.integers(1, 400))
        result = assert_same(grid, start, goal, max_expansions=budget)
        budgets_hit += not isinstance(result, np.ndarray) and "budget" in result[1]
        calls = int(rng.integers(1, 8))
        assert_same(grid, start, goal, make_cancel=lambda: cancel_after(calls))
        assert_same(grid, start, goal, max_expansions=budget, make_cancel=lambda: cancel_after(calls))
    assert budgets_hit > 0


@pytest.mark.parametrize("kind, seed", [("blobs", 2), ("iid10", 2), ("iid20", 3)])
def test_same_paths_on_the_benchmark_grids(kind, seed):
    """The 1000 x 1000 grids the speed target is measured on, corner to corner and between inner cells."""
    grid = bench_grid(kind, seed)
    assert_same(grid, (0.5, 0.5), (999.5, 999.5))
    rng = np.random.default_rng(seed)
    assert_same(grid, random_point(rng, grid, 1.0), random_point(rng, grid, 1.0))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(occupied=arrays(bool, st.tuples(st.integers(1, 24), st.integers(1, 24))),
       cells=st.tuples(st.floats(0, 1, exclude_max=True), st.floats(0, 1, exclude_max=True),
                       st.floats(0, 1, exclude_max=True), st.floats(0, 1, exclude_max=True)),
       heuristic=st.sampled_from(["octile", "euclidean"]),
       budget=st.one_of(st.none(), st.integers(1, 30)))
def test_same_outcome_on_any_small_grid(occupied, cells, heuristic, budget):
    ny, nx = occupied.shape
    grid = OccupancyGrid((0.0, 0.0), 1.0, occupied)
    start = (cells[0] * nx, cells[1] * ny)
    goal = (cells[2] * nx, cells[3] * ny)
    assert_same(grid, start, goal, heuristic=heuristic, max_expansions=budget)
