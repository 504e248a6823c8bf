"""The whole reference mission headless (routes + both vehicles' flight + scoring). Prints medians.

    python benchmarks/bench_mission.py [MISSION.yaml] [--repeat N] [--variant V]

Target (docs/results.md, "Speed and resources"): >= 500x real time. The speed factor is simulated seconds
over wall seconds; CPU seconds are printed too, since a shared machine inflates wall time.
"""

from __future__ import annotations

import argparse
import statistics
import time

from uav_model.mission import VARIANTS, load_mission
from companion.planning.routes import plan_routes
from companion.planning.flight.headless import simulate
from companion.bench.machine import machine_line


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mission", nargs="?", default="missions/paper_reference.yaml")
    parser.add_argument("--repeat", type=int, default=7)
    parser.add_argument("--variant", choices=VARIANTS, default=None)
    args = parser.parse_args()
    print(machine_line(), flush=True)
    mission = load_mission(args.mission)
    if args.variant:
        mission = mission.with_variant(args.variant)
    rows = []
    for _ in range(args.repeat):
        w0, c0 = time.perf_counter(), time.process_time()
        routes = plan_routes(mission) if mission.planner.variant.startswith("astar") else {}
        w1, c1 = time.perf_counter(), time.process_time()
        run = simulate(mission, routes=routes)
        w2, c2 = time.perf_counter(), time.process_time()
        rows.append((w2 - w0, c2 - c0, w1 - w0, w2 - w1, c2 - c1, run))
    run = rows[-1][-1]
    sim_s = run.summary.duration_s
    ticks = sum(len(t) for t in run.ticks.values())
    med = [statistics.median(r[i] for r in rows) for i in range(5)]
    print(f"{mission.name} [{mission.planner.variant}]: {sim_s:.1f} s simulated, {ticks} vehicle-ticks, "
          f"success={run.summary.success}, a={run.summary.vehicles[mission.by_priority[0].name].flight_time_s:.1f} s")
    print(f"median over {args.repeat} runs:")
    print(f"  routes (A* + sparse)      {med[2] * 1e3:8.1f} ms wall")
    print(f"  flight + scoring          {med[3] * 1e3:8.1f} ms wall   {med[4] * 1e3:8.1f} ms CPU   "
          f"{med[3] / ticks * 1e3:.3f} ms wall per vehicle-tick")
    print(f"  whole mission             {med[0] * 1e3:8.1f} ms wall   {med[1] * 1e3:8.1f} ms CPU")
    print(f"  speed factor              {sim_s / med[0]:8.0f}x real time (wall)   {sim_s / med[1]:.0f}x (CPU)"
          f"   target >= 500x")


if __name__ == "__main__":
    main()
