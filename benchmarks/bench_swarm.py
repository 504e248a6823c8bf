"""The headless swarm: real-time factor for 2 to 32 vehicles, and the cost of a tick against the
neighbours in reach.

For each fleet size N (default 2, 4, 8, 16, 32) it draws ``--scenarios`` scenarios of
``--seed`` with the bench's generator (``companion bench --vehicles N``: vehicle i on the
square's perimeter, flying through the centre to the point opposite, 5 static and 2 moving
obstacles), flies each headless with each of ``--variants`` (default ``astar-bdwa`` and
``astar-bdwa-timed``) ``--repeats`` times, and prints, as medians:

- the real-time factor: simulated seconds over wall seconds, and over this process's CPU
  seconds (less moved by other load on the machine), of :func:`simulate` (routes given,
  so A* is not counted; the timed variant's forecast and space-time plan and the scoring are);
- the wall milliseconds per tick of the whole fleet and per vehicle-tick;
- the planner's milliseconds per vehicle-tick, binned by the number of other vehicles in reach
  at that tick (closer than 2 x cruise x prediction time + the minimum separation: where two
  vehicles' rollouts can meet), over every size's runs together.

It also flies ``missions/eight_converging.yaml`` (8 vehicles, no obstacles, the figure the
300x target is set against) and, with ``--profile N``, prints the top functions of a cProfile of
one N-vehicle run of each variant. ``--numpy`` runs the planner's numpy kernels (the path without
the ``fast`` extra) instead of numba's. No pass/fail: on a shared machine the figures move with the load (the first
line names the CPU and the load average).

    python benchmarks/bench_swarm.py [--sizes 2,4,8,16,32] [--scenarios 3] [--repeats 1] [--seed 4242]
                                     [--variants astar-bdwa,astar-bdwa-timed] [--profile 8] [--numpy]
"""

from __future__ import annotations

import sys

if "--numpy" in sys.argv:  # before any import: the DWA's backend is chosen when its configs are built
    sys.modules["numba"] = None

import argparse
import cProfile
import io
import pstats
import statistics
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from companion.bench.machine import machine_line
from companion.planning.flight.headless import simulate
from companion.planning.routes import plan_routes
from companion.scenarios import ScenarioConfig, ScenarioError, generate_scenario
from uav_model.mission import Mission, load_mission

ROOT = Path(__file__).resolve().parents[1]
BINS = ((0, 0), (1, 1), (2, 2), (3, 3), (4, 7), (8, 15), (16, 31))


def reach_m(mission: Mission) -> float:
    v = max(mission.vehicles, key=lambda s: s.speed_m_s * mission.planner.prediction_time_for(s))
    return 2.0 * v.speed_m_s * mission.planner.prediction_time_for(v) + mission.safety.min_separation_m


def in_reach_counts(run, mission: Mission) -> list[tuple[int, float]]:
    """(other vehicles in reach, planner ms) per vehicle-tick flown."""
    names = list(run.tracks)
    dt = mission.planner.dt_s
    t_end = max(float(tr.t_s[-1]) for tr in run.tracks.values())
    t = np.arange(0.0, t_end + dt / 2, dt)
    xy = np.stack([np.stack(run.tracks[n].at(t), axis=-1) for n in names])  # (N, T, 2)
    d = np.linalg.norm(xy[:, None] - xy[None, :], axis=-1)  # (N, N, T)
    near = (d < reach_m(mission)).sum(axis=1) - 1  # (N, T), self excluded
    out = []
    for i, n in enumerate(names):
        for k, tick in enumerate(run.ticks[n]):
            if not tick.arrived and k < near.shape[1]:
                out.append((int(near[i, k]), tick.planner_ms))
    return out


def fly(mission: Mission, routes, variant: str, repeats: int) -> tuple[list[float], list[float], object, int]:
    """Real-time factors of wall and of this process's CPU time, the last run, its vehicle-ticks."""
    factors, cpu_factors, run = [], [], None
    for _ in range(repeats):
        cpu = time.process_time()
        run = simulate(mission, variant, routes=routes)
        factors.append(run.speed_factor)
        cpu_factors.append(run.summary.duration_s / max(time.process_time() - cpu, 1e-9))
    ticks = sum(len(t) for t in run.ticks.values())
    return factors, cpu_factors, run, ticks


def sizes_table(args: argparse.Namespace, variant: str, sizes: list[int],
                by_near: dict[int, list[float]]) -> None:
    print(f"\n[{variant}]\n{'N':>3} {'runs':>5} {'ok':>4} {'x real time':>12} {'x of CPU':>10} {'ms/fleet tick':>14} "
          f"{'ms/vehicle tick':>16} {'planner ms/veh tick':>20} {'min sep m':>10}")
    for n in sizes:
        try:
            cfg = ScenarioConfig(vehicles=n)
        except ScenarioError as exc:
            raise SystemExit(f"bench_swarm: {exc}") from None
        rtf, cpu_rtf, fleet_ms, veh_ms, plan_ms, seps, ok, runs = [], [], [], [], [], [], 0, 0
        for index in range(args.scenarios):
            sc = generate_scenario(args.seed, index, cfg)
            factors, cpu_factors, run, ticks = fly(sc.mission, sc.routes, variant, args.repeats)
            cpu_rtf += cpu_factors
            runs += len(factors)
            ok += run.success * len(factors)
            rtf += factors
            fleet_ms.append(1e3 * run.wall_s / max(len(t) for t in run.ticks.values()))
            veh_ms.append(1e3 * run.wall_s / ticks)
            counts = in_reach_counts(run, sc.mission)
            plan_ms.append(statistics.fmean(ms for _, ms in counts))
            for near, ms in counts:
                by_near[near].append(ms)
            seps.append(run.summary.min_separation_m)
        print(f"{n:>3} {runs:>5} {ok:>4} {statistics.median(rtf):>11.1f}x {statistics.median(cpu_rtf):>9.1f}x "
              f"{statistics.median(fleet_ms):>14.2f} "
              f"{statistics.median(veh_ms):>16.3f} {statistics.median(plan_ms):>20.3f} {min(seps):>10.1f}", flush=True)


def near_table(variant: str, by_near: dict[int, list[float]]) -> None:
    print(f"\n[{variant}] planner ms per vehicle-tick by other vehicles in reach (all sizes):")
    print(f"{'in reach':>9} {'ticks':>8} {'median ms':>10} {'mean ms':>8} {'p90 ms':>7}")
    for lo, hi in BINS:
        values = [ms for k, v in by_near.items() if lo <= k <= hi for ms in v]
        if values:
            label = f"{lo}" if lo == hi else f"{lo}-{hi}"
            print(f"{label:>9} {len(values):>8} {statistics.median(values):>10.3f} {statistics.fmean(values):>8.3f} "
                  f"{float(np.percentile(values, 90)):>7.3f}")


def profile(args: argparse.Namespace, variant: str) -> None:
    sc = generate_scenario(args.seed, 0, ScenarioConfig(vehicles=args.profile))
    prof = cProfile.Profile()
    started = time.perf_counter()
    prof.enable()
    run = simulate(sc.mission, variant, routes=sc.routes)
    prof.disable()
    wall = time.perf_counter() - started
    out = io.StringIO()
    pstats.Stats(prof, stream=out).sort_stats("tottime").print_stats(18)
    print(f"\n[{variant}] profile of one {args.profile}-vehicle run ({run.summary.duration_s:.0f} s flown, "
          f"{wall:.2f} s wall under the profiler), by own time:")
    print("\n".join(line for line in out.getvalue().splitlines() if line.strip()))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", default="2,4,8,16,32")
    p.add_argument("--scenarios", type=int, default=3)
    p.add_argument("--repeats", type=int, default=1)
    p.add_argument("--seed", type=int, default=4242)
    p.add_argument("--variants", default="astar-bdwa,astar-bdwa-timed")
    p.add_argument("--profile", type=int, default=None, metavar="N")
    p.add_argument("--numpy", action="store_true", help="the planner's numpy kernels instead of numba's")
    args = p.parse_args()
    sizes = [int(s) for s in args.sizes.split(",")]
    variants = args.variants.split(",")
    print(machine_line(), flush=True)
    print(f"seed {args.seed}, {args.scenarios} scenarios x {args.repeats} repeats per size, "
          f"kernels: {'numpy' if args.numpy else 'numba where installed'}", flush=True)
    converging = load_mission(ROOT / "missions" / "eight_converging.yaml")
    conv_routes = plan_routes(converging)
    for variant in variants:
        simulate(converging, variant, routes=conv_routes)  # warm: kernels compiled, caches filled
        factors, cpu_factors, run, _ = fly(converging, conv_routes, variant, max(args.repeats, 3))
        print(f"[{variant}] eight_converging.yaml: {statistics.median(factors):.0f}x real time, "
              f"{statistics.median(cpu_factors):.0f}x of CPU (medians of {len(factors)}; "
              f"{run.summary.duration_s:.0f} s flown in {run.wall_s:.2f} s), success {run.success}", flush=True)
    for variant in variants:
        by_near: dict[int, list[float]] = defaultdict(list)
        sizes_table(args, variant, sizes, by_near)
        near_table(variant, by_near)
        if args.profile:
            profile(args, variant)


if __name__ == "__main__":
    main()
