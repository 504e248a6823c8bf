"""What the timed variant costs against the paper's: CPU per vehicle-tick of a headless flight.

    python benchmarks/bench_timed_cost.py [--scenarios 6] [--seed 7] [--repeats 3] [--baseline DIR]

For the reference missions and the bench's generated scenarios (``--scenarios`` of ``--seed``),
each flown by ``astar-bdwa`` (the paper's variant) and ``astar-bdwa-timed``: the CPU of the whole
mission (for the timed variant: the first vehicle's forecast, flown alone, and the space-time
plan, then the flight; the A* routes, shared by both, are left out) over the vehicle-ticks flown,
and the timed variant's over the paper variant's (target: at most 2). The occlusion certificate
is not part of either. Each repeat runs in a fresh process, the kinds alternately (this tree,
then ``--baseline DIR``, another tree of the project); the figures are medians over the repeats.
Before the clock each process loads the compiled DWA kernels and flies the first mission once
with each variant, thrown away: the schedule and space-time kernels only the timed variant uses
load on first use (tens of ms, once per process), which would otherwise be charged to the first
mission measured.
The CPU model is printed first: compare ratios across machines, not milliseconds.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

from companion.bench.machine import machine_line

ROOT = Path(__file__).resolve().parents[1]
MISSIONS = ("missions/paper_reference.yaml", "missions/small_reference.yaml")
VARIANTS = ("astar-bdwa", "astar-bdwa-timed")

# Runs in the child: every mission flown by both variants, the CPU and vehicle-ticks of each as JSON.
_CHILD = """
import json, sys, time
from uav_model.mission import load_mission
from companion.planning.dwa.step import warm_up_kernels
from companion.planning.flight.forecast import first_forecast
from companion.planning.flight.headless import simulate
from companion.planning.routes import plan_routes
from companion.scenarios import ScenarioConfig, generate_scenario
seed, count, variants, files = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3].split(","), sys.argv[4:]
missions = [(f, load_mission(f), None) for f in files]
for i in range(count):
    s = generate_scenario(seed, i, ScenarioConfig())
    missions.append((s.doc["name"], s.mission, s.routes))
missions = [(name, mission, plan_routes(mission) if routes is None else routes) for name, mission, routes in missions]
warm_up_kernels()


def fly(mission, routes, variant):  # the whole mission: the timed variant's forecast and plan too
    m = mission.with_variant(variant)
    return simulate(m, routes=routes, first=first_forecast(m, routes) if variant.endswith("-timed") else None)


for variant in variants:  # thrown away: loads the compiled code only the timed variant uses
    fly(*missions[0][1:], variant)
out = {}
for name, mission, routes in missions:
    for variant in variants:
        cpu0 = time.process_time()
        run = fly(mission, routes, variant)
        out[f"{name}|{variant}"] = {"cpu": time.process_time() - cpu0,
                                    "ticks": sum(len(t) for t in run.ticks.values())}
print(json.dumps(out))
"""


def _repeat(tree: Path, args: argparse.Namespace) -> dict:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    done = subprocess.run([sys.executable, "-c", _CHILD, str(args.seed), str(args.scenarios), ",".join(VARIANTS),
                           *(str(tree / m) for m in MISSIONS)], env=env, cwd=tree, capture_output=True, text=True)
    if done.returncode:
        sys.exit(f"bench_timed_cost: the run in {tree} failed:\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", type=int, default=6, help="generated scenarios of --seed (0..N-1)")
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--baseline", type=Path, default=None, metavar="DIR", help="also time the tree in DIR")
    args = parser.parse_args()
    print(machine_line(), flush=True)
    kinds = {"this tree": ROOT}
    if args.baseline is not None:
        if not (args.baseline / "companion").is_dir():
            sys.exit(f"bench_timed_cost: --baseline {args.baseline} is not a tree of the project")
        kinds[f"baseline {args.baseline}"] = args.baseline.resolve()
    runs: dict[str, list[dict]] = {k: [] for k in kinds}
    for _ in range(args.repeats):
        for kind, tree in kinds.items():
            runs[kind].append(_repeat(tree, args))
    for kind, repeats in runs.items():
        print(f"\n{kind}: CPU ms per vehicle-tick (median of {args.repeats}), forecast and plan included")
        print(f"{'mission':28} {'astar-bdwa':>10} {'timed':>8} {'timed / paper':>13}")
        names = sorted({key.split('|')[0] for key in repeats[0]}, key=lambda n: (not n.endswith(".yaml"), n))
        totals = {v: [0.0] * len(repeats) for v in VARIANTS}
        ticks = {v: 0 for v in VARIANTS}
        for name in names:
            per = {}
            for v in VARIANTS:
                cells = [r[f"{name}|{v}"] for r in repeats]
                per[v] = statistics.median(1e3 * c["cpu"] / c["ticks"] for c in cells)
                for k, c in enumerate(cells):
                    totals[v][k] += c["cpu"]
                ticks[v] += cells[0]["ticks"]
            print(f"{Path(name).name:28} {per[VARIANTS[0]]:10.3f} {per[VARIANTS[1]]:8.3f} "
                  f"{per[VARIANTS[1]] / per[VARIANTS[0]]:13.2f}")
        paper, timed = (1e3 * statistics.median(totals[v]) / ticks[v] for v in VARIANTS)
        print(f"{'all missions':28} {paper:10.3f} {timed:8.3f} {timed / paper:13.2f}   (target: timed / paper <= 2)")


if __name__ == "__main__":
    main()
