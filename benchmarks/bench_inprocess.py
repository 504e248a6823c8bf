"""``companion run --in-process``: the reference flight's wall time with no stub process and no sockets.

Flies the mission ``--repeats`` times through the companion's own runner (pilots, monitors, flight
log, scoring; no output directory, so no plot) on the in-process fleet, and prints the median wall
time, the sim time flown, each vehicle's flight time beside ``companion simulate``'s, and whether
every repeat flew exactly the same flight times (it should: the sim waits for the companion). No
pass/fail.

    python benchmarks/bench_inprocess.py [--mission M] [--repeats 3] [--speedup S] [--wire]
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import time
from pathlib import Path

from companion.app.flight_plan import prepare
from companion.app.pilot import RunSettings
from companion.app.live_run import run_mission
from uav_model.mission import load_mission
from companion.planning.flight.headless import simulate
from companion.sitl.inprocess import InProcessOptions, open_inprocess_fleet
from companion.bench.machine import machine_line

ROOT = Path(__file__).resolve().parents[1]


async def _fly(plan, options: InProcessOptions):
    async with open_inprocess_fleet(plan.mission, options) as fleet:
        result = await run_mission(plan, fleet.connections(), RunSettings(), None, lambda line: None,
                                   open_vehicle=fleet.open_vehicle)
        return result, fleet.sim_time_s


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--mission", type=Path, default=ROOT / "missions" / "paper_reference.yaml")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--speedup", type=float, default=None, help="pace the sim (default: as fast as the loop turns)")
    p.add_argument("--wire", action="store_true", help="pack and parse every message both ways")
    args = p.parse_args()
    print(machine_line(), flush=True)

    mission = load_mission(args.mission)
    plan = prepare(mission, None)
    headless = simulate(mission).summary
    options = InProcessOptions(speedup=args.speedup, wire=args.wire)
    walls, sims, flights, ok = [], [], [], 0
    for _ in range(args.repeats):
        started = time.perf_counter()
        result, sim_s = asyncio.run(_fly(plan, options))
        walls.append(time.perf_counter() - started)
        sims.append(sim_s)
        ok += result.success
        flights.append({n: v.flight_time_s for n, v in result.summary.vehicles.items()} if result.summary else {})
    wall = statistics.median(walls)
    print(f"{mission.name}: in-process run, median of {args.repeats}: {wall:.2f} s wall "
          f"(runs {', '.join(f'{w:.2f}' for w in walls)}); {statistics.median(sims):.0f} s sim "
          f"-> {statistics.median(sims) / wall:.0f}x real time; {ok}/{args.repeats} succeeded")
    for name, v in headless.vehicles.items():
        flown = [f.get(name) for f in flights]
        ratio = [f / v.flight_time_s for f in flown if f is not None]
        print(f"  {name}: flight {', '.join('-' if f is None else f'{f:.1f}' for f in flown)} s vs simulate "
              f"{v.flight_time_s:.1f} s (ratio {', '.join(f'{r:.4f}' for r in ratio)})")
    print(f"  identical flight times in every repeat: {all(f == flights[0] for f in flights)}")


if __name__ == "__main__":
    main()
