"""One BDWA tick: 31 yaw-rate samples, p = 11 s at dt = 0.5 s, 7 obstacles (circles, a rectangle,
a triangle and a polygon; two of them moving), the other UAV in view. Prints medians.

    python benchmarks/bench_dwa.py [--repeat N]

Target (docs/results-reference.md): <= 1 ms per UAV per tick.
"""

from __future__ import annotations

import argparse
import statistics
import time

from companion.mission import parse_mission
from companion.planning.dwa import OtherUav, Pose, plan_step
from companion.planning.fusion import ObstacleField, VehiclePlanner

MISSION = """
name: bench_dwa
area: {x_min_m: 0, y_min_m: 0, x_max_m: 3181.98, y_max_m: 3181.98}
stations: {A: [0, 0], B: [3181.98, 3181.98]}
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
vehicles:
  - {name: a, start: A, goal: B, initial_heading_deg: 45}
  - {name: b, start: B, goal: A, initial_heading_deg: -135}
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5000)
    args = parser.parse_args()
    mission = parse_mission(MISSION, "bench_dwa")
    vb = mission.by_priority[1]
    planner = VehiclePlanner.build(mission, vb, None, "bdwa")
    field = ObstacleField.from_world(mission.world)
    pose = Pose(1250.0, 1500.0, 0.3)
    other = OtherUav(1900.0, 1000.0, -7.0, 7.0)
    snapshot = field.at_time(60.0)
    goal = (3181.98, 3181.98)
    cfg = planner.config

    def timed(fn, n):
        samples = []
        for _ in range(n):
            t0 = time.perf_counter()
            fn()
            samples.append((time.perf_counter() - t0) * 1e3)
        return statistics.median(samples), statistics.quantiles(samples, n=100)[98]

    result = plan_step(pose, goal, other, snapshot, cfg)
    print(f"config: {cfg.samples} samples x {cfg.steps} steps (p = {cfg.prediction_time_s:g} s, dt = {cfg.dt_s:g} s), "
          f"{snapshot.count} obstacles ({len(snapshot.poly_ids)} polygons, {len(mission.world.moving_obstacles)} moving)")
    print(f"decision: {result}")
    med, p99 = timed(lambda: plan_step(pose, goal, other, snapshot, cfg), args.repeat)
    print(f"plan_step (BDWA core)           median {med:.3f} ms   p99 {p99:.3f} ms")
    med, p99 = timed(lambda: field.at_time(60.0), args.repeat)
    print(f"ObstacleField.at_time (snapshot) median {med:.3f} ms   p99 {p99:.3f} ms")
    med, p99 = timed(lambda: planner.tick(pose, other, field.at_time(60.0), 60.0), args.repeat)
    print(f"VehiclePlanner.tick incl. snapshot median {med:.3f} ms   p99 {p99:.3f} ms   (target <= 1 ms per UAV)")


if __name__ == "__main__":
    main()
