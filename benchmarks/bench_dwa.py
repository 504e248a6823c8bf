"""One BDWA tick: 31 yaw-rate samples, p = 11 s at dt = 0.5 s, 7 obstacles (circles, a rectangle,
a triangle and a polygon; two of them moving), the other UAV in view. Prints medians.

    python benchmarks/bench_dwa.py [--repeat N]

Two worlds: "spread" (obstacles over the whole area, as in the random scenarios; most are culled
because no rollout can reach them) and "clutter" (all 7 within one rollout length of the UAV, so
every obstacle is evaluated against every rollout point: the worst case).
Target (docs/results.md, "Speed and resources"): <= 1 ms per UAV per tick.
The same step with the astar-bdwa-timed window (4 speeds x 31 rates, sloped sightline, fixed
scales) is timed in alternating rounds with the paper's window; with numba installed, each also
on the numpy kernels (the code without numba). Wall medians, and CPU per call (shared machine).
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time

import numpy as np

from uav_model.mission import parse_mission
from companion.planning.dwa import Command, OtherUav, Pose, plan_step
from companion.planning.dwa.backend import COMPILED, NUMPY
from companion.planning.obstacle_field import ObstacleField
from companion.planning.variants import window_settings
from companion.planning.vehicle_planner import VehiclePlanner
from companion.bench.machine import machine_line

HEAD = """
area: {x_min_m: 0, y_min_m: 0, x_max_m: 3181.98, y_max_m: 3181.98}
stations: {A: [0, 0], B: [3181.98, 3181.98]}
vehicles:
  - {name: a, start: A, goal: B, initial_heading_deg: 45}
  - {name: b, start: B, goal: A, initial_heading_deg: -135}
"""
WORLDS = {
    "spread": (HEAD + """
obstacles:
  - {id: c1, shape: circle, center: [900, 700], radius_m: 300}
  - {id: c2, shape: circle, center: [2200, 2500], radius_m: 200}
  - {id: r1, shape: rectangle, center: [1500, 1200], width_m: 400, height_m: 250, rotation_deg: 30}
  - {id: t1, shape: triangle, center: [2400, 1500], circumradius_m: 300, rotation_deg: 10}
  - {id: p1, shape: polygon, vertices: [[1000, 2000], [1400, 1900], [1500, 2300], [1200, 2500], [950, 2300]]}
  - {id: m1, shape: circle, center: [600, 1500], radius_m: 120,
     motion: {type: shuttle, to: [1600, 1500], speed_m_s: 4}}
  - {id: m2, shape: circle, center: [2000, 600], radius_m: 100,
     motion: {type: shuttle, to: [2000, 1800], speed_m_s: 3}}
""", Pose(1250.0, 1500.0, 0.3)),
    "clutter": (HEAD + """
obstacles:
  - {id: c1, shape: circle, center: [1090, 1075], radius_m: 20}
  - {id: c2, shape: circle, center: [930, 1090], radius_m: 25}
  - {id: r1, shape: rectangle, center: [1070, 930], width_m: 40, height_m: 30, rotation_deg: 30}
  - {id: t1, shape: triangle, center: [960, 920], circumradius_m: 25, rotation_deg: 10}
  - {id: p1, shape: polygon, vertices: [[1130, 990], [1170, 990], [1170, 1010], [1145, 1010], [1145, 1040], [1130, 1040]]}
  - {id: m1, shape: circle, center: [1150, 1100], radius_m: 15,
     motion: {type: shuttle, to: [800, 1100], speed_m_s: 5}}
  - {id: m2, shape: circle, center: [880, 880], radius_m: 15,
     motion: {type: shuttle, to: [1200, 1200], speed_m_s: 3}}
""", Pose(1000.0, 1000.0, 0.3)),
}


def timed(fn, n: int) -> tuple[float, float]:
    samples = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        samples.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(samples), statistics.quantiles(samples, n=100)[98]


def interleaved(fns: dict, n: int, rounds: int = 10) -> dict[str, tuple[float, float, float]]:
    """Median and p99 wall ms per call, and CPU ms per call (the median over rounds), per
    function, run in alternating rounds so that a shared machine's load falls on all alike."""
    samples: dict[str, list[float]] = {k: [] for k in fns}
    cpu: dict[str, list[float]] = {k: [] for k in fns}
    per_round = max(1, n // rounds)
    for _ in range(rounds):
        for k, fn in fns.items():
            c0 = time.process_time()
            for _ in range(per_round):
                t0 = time.perf_counter()
                fn()
                samples[k].append((time.perf_counter() - t0) * 1e3)
            cpu[k].append((time.process_time() - c0) * 1e3 / per_round)
    return {k: (statistics.median(v), statistics.quantiles(v, n=100)[98], statistics.median(cpu[k]))
            for k, v in samples.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3000)
    args = parser.parse_args()
    print(machine_line(), flush=True)
    for name, (text, pose) in WORLDS.items():
        mission = parse_mission(text, f"bench_dwa_{name}")
        planner = VehiclePlanner.build(mission, mission.by_priority[1], None, "bdwa")
        field = ObstacleField.from_world(mission.world)
        other = OtherUav(pose.x_m + 600.0, pose.y_m - 500.0, -7.0, 7.0)
        snapshot = field.at_time(0.0)
        goal = (3181.98, 3181.98)
        cfg = planner.config
        timed_cfg = dataclasses.replace(cfg, **window_settings(mission, "astar-bdwa-timed"))
        result = plan_step(pose, goal, other, snapshot, cfg)
        near = snapshot.near(pose.x_m, pose.y_m, cfg.reach_m + cfg.distance_saturation_m, cfg.prediction_time_s)
        print(f"[{name}] {cfg.samples} samples x {cfg.steps} steps (p = {cfg.prediction_time_s:g} s, "
              f"dt = {cfg.dt_s:g} s); {snapshot.count} obstacles ({len(snapshot.poly_ids)} polygons, "
              f"{len(mission.world.moving_obstacles)} moving), {near.count} within reach; "
              f"{result.legal_count if isinstance(result, Command) else 0} legal rollouts")
        paper = lambda: plan_step(pose, goal, other, snapshot, cfg)  # noqa: E731
        timed_window = lambda: plan_step(pose, goal, other, snapshot, timed_cfg)  # noqa: E731
        fns = {"paper": paper, "timed": timed_window}
        if COMPILED is not None:  # numba: the numpy backend beside, interleaved
            paper_np, timed_np = (dataclasses.replace(c, backend=NUMPY) for c in (cfg, timed_cfg))
            fns.update({"paper, numpy": lambda: plan_step(pose, goal, other, snapshot, paper_np),
                        "timed, numpy": lambda: plan_step(pose, goal, other, snapshot, timed_np)})
        for key, (med, p99, cpu) in interleaved(fns, args.repeat).items():
            window = (f"timed window ({timed_cfg.count} rollouts)" if key.startswith("timed")
                      else f"paper window ({cfg.count} rollouts)")
            kind = "numpy kernels" if key.endswith("numpy") else ("numba kernels" if len(fns) > 2 else "numpy")
            print(f"  plan_step, {window:27} {kind:13} median {med:.3f} ms  p99 {p99:.3f} ms  cpu {cpu:.3f} ms")
        med, p99 = timed(lambda: field.at_time(60.0), args.repeat)
        print(f"  ObstacleField.at_time (snapshot)   median {med:.3f} ms   p99 {p99:.3f} ms")
        snapshots = field.at_times(0.5 * np.arange(args.repeat * 2 + 1))
        med, p99 = timed(lambda: next(snapshots), args.repeat)
        print(f"  ObstacleField.at_times (runner)    median {med:.3f} ms   p99 {p99:.3f} ms   per tick")
        med, p99 = timed(lambda: planner.tick(pose, other, next(snapshots), 0.0), args.repeat)
        print(f"  VehiclePlanner.tick + snapshot     median {med:.3f} ms   p99 {p99:.3f} ms   (fresh at_times "
              "snapshot each tick, as the runner)")


if __name__ == "__main__":
    main()
