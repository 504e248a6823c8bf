"""Global-planning timings: rasterise + A*, A* on big grids beside pyastar2d, sparse optimisation, routes, bounds.

Prints the CPU, then medians (and min) over repeats; no pass/fail. Targets: rasterise + A* on the
reference map at 10 m <= 50 ms; A* on a 1000 x 1000 grid of 20 % random blocked cells <= 0.3 s;
on the disc grids at most pyastar2d's time (ratio <= 1.0).

    python benchmarks/bench_astar.py [--repeats 7] [--reference] [--python]

The 1000 x 1000 grids run ours and pyastar2d (``pip install pyastar2d``) in turn, run by run, so
both medians come from the same window of a shared machine's drifting speed; the ratio is ours over
theirs, the median of the run-by-run ratios. pyastar2d cuts corners and charges a diagonal move as
a straight one, so its paths are longer in metres: both lengths are printed (ours is the optimum
under no corner cutting with diagonals of sqrt 2 cells). --python adds our search without numba;
--reference the frozen pre-speed-up A* (tests/planning/astar_reference.py).
"""

from __future__ import annotations

import argparse
import importlib.util
import statistics
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from uav_model.mission import load_mission
from companion.planning import astar_jit
from companion.planning.astar import astar, path_length_m
from companion.planning.bounds import inscribed_outline, lower_bound_m
from companion.planning.grid import OccupancyGrid, rasterise
from companion.planning.routes import plan_routes
from companion.planning.sparse import sparsify
from uav_model.world import make_obstacle
from companion.bench.machine import machine_line

REFERENCE = Path(__file__).resolve().parents[1] / "missions" / "paper_reference.yaml"
ORACLE = Path(__file__).resolve().parents[1] / "tests" / "planning" / "astar_reference.py"


def measure(fn: Callable[[], object], repeats: int) -> tuple[float, float, object]:
    """(median ms, min ms, last result)."""
    times, result = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times), min(times), result


def random_grid(kind: str, seed: int, n: int = 1000) -> OccupancyGrid:
    rng = np.random.default_rng(seed)
    if kind.startswith("iid"):
        occ = rng.random((n, n)) < float(kind[3:]) / 100.0
    else:  # blobs: 60 random discs, ~35 % of the cells
        yy, xx = np.mgrid[0:n, 0:n]
        occ = np.zeros((n, n), dtype=bool)
        for _ in range(60):
            cx, cy = rng.uniform(0, n, 2)
            r = rng.uniform(0.02 * n, 0.08 * n)
            occ |= (xx - cx) ** 2 + (yy - cy) ** 2 < r * r
    occ[0, 0] = occ[-1, -1] = False
    return OccupancyGrid((0.0, 0.0), 1.0, occ)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--reference", action="store_true",
                        help="also time the pre-speed-up A*, alternating run by run")
    parser.add_argument("--python", action="store_true",
                        help="also time our search without numba, alternating run by run")
    args = parser.parse_args()
    print(machine_line(), flush=True)
    rep = args.repeats
    mission = load_mission(REFERENCE)
    world = mission.world
    a, b = mission.stations["A"], mission.stations["B"]
    res = mission.planner.grid_resolution_m

    rows: list[tuple[str, float, float, str]] = []

    def row(name: str, fn: Callable[[], object], note: Callable[[object], str] = lambda _: "", repeats: int = rep):
        med, best, out = measure(fn, repeats)
        rows.append((name, med, best, note(out)))
        print(f"{name:<48} median {med:9.2f} ms   min {best:9.2f} ms   {rows[-1][3]}", flush=True)

    row(f"rasterise reference @ {res:g} m", lambda: rasterise(world, res),
        lambda g: f"{g.shape[1]} x {g.shape[0]} cells, {int(g.occupied.sum())} occupied")
    grid = rasterise(world, res)
    row("A* reference A -> B", lambda: astar(grid, a, b), lambda p: f"{len(p)} nodes")
    row("rasterise + A* reference (target <= 50 ms)", lambda: astar(rasterise(world, res), a, b))
    raw = astar(grid, a, b)
    row("sparsify reference route (World, exact disc)", lambda: sparsify(raw, world),
        lambda s: f"{len(raw)} -> {len(s)} nodes")
    row("sparsify reference route (polygon list)", lambda: sparsify(raw, [o.inflated for o in world.static_obstacles]))
    row("plan_routes reference (a, then b constrained)", lambda: plan_routes(mission),
        lambda r: ", ".join(f"{k}: {v.nodes_raw}->{v.nodes_sparse} nodes {v.length_m:.1f} m [{v.constraint}]"
                            for k, v in r.items()))
    row("lower_bound_m reference (closed form)", lambda: lower_bound_m(world, a, b), lambda v: f"{v:.2f} m")
    aside = make_obstacle("aside", "rectangle", center=(3000.0, 200.0), width_m=50.0, height_m=50.0)
    general_world = replace(world, obstacles=world.obstacles + (aside,))
    row("lower_bound_m reference (visibility graph)", lambda: lower_bound_m(general_world, a, b),
        lambda v: f"{v:.2f} m ({len(inscribed_outline(world.obstacles[0]).exterior.coords) - 1}-gon disc)")

    print(f"\n1000 x 1000 grids, corner to corner, {max(3, rep // 2)} alternating runs "
          f"(ours: {'numba' if astar_jit.search is not None else 'Python, no numba'})", flush=True)
    for kind, seed in GRIDS:
        g = random_grid(kind, seed)
        try:
            astar(g, (0.5, 0.5), (999.5, 999.5))
        except Exception as exc:  # a walled-in draw would only time the failure
            print(f"A* 1000x1000 {kind}: {exc}")
            continue
        if args.reference:
            alternate(kind, g, max(3, rep // 2))
        side_by_side(f"{kind} seed {seed}", g, max(3, rep // 2), args.python)


GRIDS = (("blobs", 2), ("blobs", 3), ("blobs", 4), ("iid10", 2), ("iid20", 3))


def side_by_side(name: str, grid: OccupancyGrid, repeats: int, python: bool) -> None:
    """Ours and pyastar2d (and our Python search) in turn on one grid: medians, ratios, lengths."""
    try:
        import pyastar2d
    except ImportError:
        pyastar2d = None
    ny, nx = grid.shape
    weights = np.where(grid.occupied, np.inf, 1.0).astype(np.float32)
    runs: dict[str, Callable[[], np.ndarray]] = {
        "ours": lambda: astar(grid, (0.5, 0.5), (nx - 0.5, ny - 0.5))}
    if pyastar2d is not None:
        runs["pyastar2d"] = lambda: pyastar2d.astar_path(weights, (0, 0), (ny - 1, nx - 1), allow_diagonal=True)[:, ::-1] + 0.5
    if python and astar_jit.search is not None:
        def python_search() -> np.ndarray:
            compiled, astar_jit.search = astar_jit.search, None
            try:
                return astar(grid, (0.5, 0.5), (nx - 0.5, ny - 0.5))
            finally:
                astar_jit.search = compiled
        runs["ours-python"] = python_search
    times: dict[str, list[float]] = {k: [] for k in runs}
    lengths: dict[str, float] = {}
    for _ in range(repeats):
        for key, fn in runs.items():
            t0 = time.perf_counter()
            path = fn()
            times[key].append((time.perf_counter() - t0) * 1e3)
            lengths[key] = path_length_m(path)
    line = f"A* {name:<14}" + "".join(f" {k} {statistics.median(v):7.1f} ms" for k, v in times.items())
    for other in [k for k in runs if k != "ours"]:
        ratio = statistics.median(a / b for a, b in zip(times["ours"], times[other]))
        line += f"   ours/{other} {ratio:.2f}"
    line += "   length m " + ", ".join(f"{k} {v:.1f}" for k, v in lengths.items())
    print(line + f"   ({grid.occupied.mean() * 100:.0f} % blocked)", flush=True)


def alternate(kind: str, grid: OccupancyGrid, repeats: int) -> None:
    """Median ms of the reference and the current A*, run alternately on one grid."""
    spec = importlib.util.spec_from_file_location("astar_reference", ORACLE)
    assert spec is not None and spec.loader is not None
    oracle = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(oracle)
    times: dict[str, list[float]] = {"reference": [], "current": []}
    for _ in range(repeats):
        for name, fn in (("reference", oracle.astar), ("current", astar)):
            t0 = time.perf_counter()
            path = fn(grid, (0.5, 0.5), (999.5, 999.5))
            times[name].append((time.perf_counter() - t0) * 1e3)
    old, new = (statistics.median(times[k]) for k in ("reference", "current"))
    print(f"A* 1000x1000 {kind:<6} reference median {old:8.1f} ms   current median {new:8.1f} ms   "
          f"ratio {new / old:.2f}   {len(path)} nodes, {grid.occupied.mean() * 100:.0f} % blocked", flush=True)


if __name__ == "__main__":
    main()
