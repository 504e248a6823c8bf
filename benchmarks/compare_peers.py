"""Ours beside the peers, each peer doing the same work, in one interleaved run; prints ratios.

    python benchmarks/compare_peers.py [--rounds 7] [--pythonrobotics FILE]

* A* on a 1000 x 1000 grid, corner to corner: ours (``astar``) and pyastar2d (``pip install
  pyastar2d``; 8-connected, it cuts corners and charges a diagonal as a straight move), on a disc
  grid and on 20 % random blocked cells. Both path lengths are printed.
* A whole headless flight of the reference mission: ours (``simulate``, A*-BDWA) and ORCA (pyrvo,
  ``pip install -e '.[orca]'``) steering the same vehicles along the same A* routes with the same
  plant and scoring (``companion.bench.orca``).
* One local-planner decision among N circular obstacles within reach (0, 10, 50): ours
  (``plan_step``, 31 yaw rates x 22 steps) and PythonRobotics' ``dwa_control`` from
  ``dynamic_window_approach.py`` (``--pythonrobotics FILE``: it is not a package, so it is loaded
  from the file given, never copied here), configured to the same window: one speed, 31 yaw
  rates, the same horizon and time step, the same obstacles as points with the inflated radius.

Each pair runs in turn, round by round, so both sides see the same load; a ratio is the median
of the per-round ratios of CPU seconds (``time.process_time``), ours over theirs (below 1: ours is
faster). The first line names the CPU.
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from companion.bench.machine import machine_line
from companion.planning.astar import astar, path_length_m
from companion.planning.dwa import OtherUav, Pose, plan_step
from companion.planning.obstacle_field import ObstacleField
from companion.planning.routes import plan_routes
from companion.planning.flight.headless import simulate
from companion.planning.vehicle_planner import VehiclePlanner
from uav_model.mission import load_mission, parse_mission

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_astar import random_grid  # noqa: E402 (the grids bench_astar times)

REFERENCE = Path(__file__).resolve().parents[1] / "missions" / "paper_reference.yaml"
DWA_WORLD = """
area: {x_min_m: 0, y_min_m: 0, x_max_m: 3000, y_max_m: 3000}
stations: {A: [100, 100], B: [2900, 2900]}
vehicles:
  - {name: a, start: A, goal: B, initial_heading_deg: 45}
  - {name: b, start: B, goal: A, initial_heading_deg: -135}
"""
Pair = tuple[str, Callable[[], object], str, Callable[[], object]]


def cpu_s(fn: Callable[[], object]) -> tuple[float, object]:
    t0 = time.process_time()
    out = fn()
    return time.process_time() - t0, out


def run_pairs(pairs: list[Pair], rounds: int) -> dict[str, tuple[float, float, float, object, object]]:
    """Per pair: (median ours s, median theirs s, median ratio, ours' last result, theirs')."""
    ours: dict[str, list[float]] = {p[0]: [] for p in pairs}
    theirs: dict[str, list[float]] = {p[0]: [] for p in pairs}
    last: dict[str, tuple[object, object]] = {}
    for p in pairs:  # one untimed call each: numba's first call, file caches
        p[1](), p[3]()
    for _ in range(rounds):
        for name, our_fn, _, their_fn in pairs:
            a, out_a = cpu_s(our_fn)
            b, out_b = cpu_s(their_fn)
            ours[name].append(a)
            theirs[name].append(b)
            last[name] = (out_a, out_b)
    return {name: (statistics.median(ours[name]), statistics.median(theirs[name]),
                   statistics.median(a / b for a, b in zip(ours[name], theirs[name]) if b > 0),
                   *last[name]) for name, *_ in pairs}


def astar_pairs() -> list[Pair]:
    try:
        import pyastar2d
    except ImportError:
        print("pyastar2d: not installed (pip install pyastar2d); its rows are left out")
        return []
    pairs: list[Pair] = []
    for kind, seed, label in (("blobs", 2, "A* disc grid"), ("iid20", 3, "A* 20 % random cells")):
        grid = random_grid(kind, seed)
        weights = np.where(grid.occupied, np.inf, 1.0).astype(np.float32)
        pairs.append((f"{label} (1000 x 1000)", lambda g=grid: astar(g, (0.5, 0.5), (999.5, 999.5)), "pyastar2d",
                      lambda w=weights: pyastar2d.astar_path(w, (0, 0), (999, 999), allow_diagonal=True)[:, ::-1] + 0.5))
    return pairs


def orca_pairs() -> list[Pair]:
    if importlib.util.find_spec("pyrvo") is None:
        print("pyrvo: not installed (pip install -e '.[orca]'); its row is left out")
        return []
    from companion.bench.orca import simulate_orca
    mission = load_mission(REFERENCE).with_variant("astar-bdwa")
    routes = plan_routes(mission)
    return [("whole reference flight", lambda: simulate(mission, routes=routes), "pyrvo (ORCA)",
             lambda: simulate_orca(mission, routes=routes))]


def load_pythonrobotics(path: Path):
    spec = importlib.util.spec_from_file_location("pythonrobotics_dwa", path)
    if spec is None or spec.loader is None:
        raise SystemExit(f"compare_peers: {path}: not a Python file")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.show_animation = False
    return module


def dwa_pairs(path: Path, counts: tuple[int, ...]) -> list[Pair]:
    pr = load_pythonrobotics(path)
    pairs: list[Pair] = []
    rng = np.random.default_rng(7)
    pose = Pose(1500.0, 1500.0, 0.3)
    for count in counts:
        # circles in a ring around the vehicle, within one rollout's reach, clear of where it stands
        radius = rng.uniform(60.0, 110.0, count)
        angle = rng.uniform(-math.pi, math.pi, count)
        centres = np.column_stack([pose.x_m + radius * np.cos(angle), pose.y_m + radius * np.sin(angle)])
        lines = "".join(f"  - {{id: c{i}, shape: circle, center: [{x:.1f}, {y:.1f}], radius_m: 8}}\n"
                        for i, (x, y) in enumerate(centres))
        mission = parse_mission(DWA_WORLD + ("obstacles:\n" + lines if count else ""), f"peers_dwa_{count}")
        planner = VehiclePlanner.build(mission, mission.by_priority[0], None, "bdwa")
        cfg = planner.config
        snapshot = ObstacleField.from_world(mission.world).at_time(0.0)
        other = OtherUav(2900.0, 2900.0, 0.0, 0.0)  # far away: no sightline or separation work to speak of
        goal = (2900.0, 2900.0)
        inflated = mission.world.obstacles[0].inflated_radius_m if count else 10.0
        config = pr.Config()
        config.min_speed, config.max_speed = 0.0, 2.0 * cfg.speed_m_s
        config.max_accel = 1e-9  # one speed: v in [cruise - tiny, cruise + tiny) at a coarse step
        config.v_resolution = 1.0
        config.max_yaw_rate = cfg.max_yaw_rate_rad_s
        config.max_delta_yaw_rate = cfg.max_yaw_rate_rad_s / cfg.dt_s  # the whole range in one step
        config.dt = cfg.dt_s
        config.yaw_rate_resolution = 2.0 * cfg.max_yaw_rate_rad_s / cfg.samples  # cfg.samples rates
        config.predict_time = cfg.prediction_time_s - 0.5 * cfg.dt_s  # cfg.steps steps after the start
        config.robot_radius = inflated
        state = np.array([pose.x_m, pose.y_m, pose.heading_rad, cfg.speed_m_s, 0.0])
        ob = centres if count else np.empty((0, 2))
        if not count:
            ob = np.array([[1e7, 1e7]])  # its obstacle cost needs one point: far away
        pairs.append((f"DWA decision, {count} obstacles ({cfg.samples} x {cfg.steps})",
                      lambda: plan_step(pose, goal, other, snapshot, cfg), "PythonRobotics dwa_control",
                      lambda s=state, c=config, o=ob: pr.dwa_control(s.copy(), c, np.array(goal), o)))
    return pairs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--pythonrobotics", type=Path, metavar="FILE",
                        help="PythonRobotics' PathPlanning/DynamicWindowApproach/dynamic_window_approach.py")
    args = parser.parse_args()
    if args.rounds < 1:
        parser.error("--rounds must be at least 1")
    if args.pythonrobotics is not None and not args.pythonrobotics.is_file():
        print(f"compare_peers: --pythonrobotics {args.pythonrobotics}: no such file", file=sys.stderr)
        raise SystemExit(2)
    print(machine_line(), flush=True)
    pairs = astar_pairs() + orca_pairs()
    if args.pythonrobotics is not None:
        pairs += dwa_pairs(args.pythonrobotics, (0, 10, 50))
    else:
        print("PythonRobotics' DWA: left out (give --pythonrobotics FILE)")
    print(f"{'work':<44} {'peer':<28} {'ours CPU ms':>12} {'peer CPU ms':>12} {'ours/peer':>10}  notes", flush=True)
    results = run_pairs(pairs, args.rounds)
    for name, _, peer, _ in pairs:
        ours_s, theirs_s, ratio, out_a, out_b = results[name]
        note = ""
        if name.startswith("A*"):
            note = f"path m: ours {path_length_m(out_a):.1f}, peer {path_length_m(out_b):.1f}"
        elif name.startswith("whole"):
            note = (f"{out_a.summary.duration_s:.0f} s flown by ours, {out_b.summary.duration_s:.0f} s by the peer; "
                    f"success {out_a.success} / {out_b.success}")
        print(f"{name:<44} {peer:<28} {ours_s * 1e3:12.2f} {theirs_s * 1e3:12.2f} {ratio:10.3f}  {note}", flush=True)


if __name__ == "__main__":
    main()
