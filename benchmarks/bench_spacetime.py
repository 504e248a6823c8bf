"""Coordinated-timing timings on the reference mission (10 m cells): the pre-flight space-time plan
and the occlusion certificate. Prints medians over repeats, wall and CPU time (this machine is
shared: CPU time is what the code costs, wall what it waited); no pass/fail.
Target (docs/results.md, "Speed and resources"): the pre-flight space-time plan <= 2 s on the reference.

    python benchmarks/bench_spacetime.py [--repeats 5] [--scenarios N --seed S]

--scenarios also certifies and plans (a may hold 300 s) the first N random scenarios of seed S
(SPEC §3), one line each.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

from uav_model.mission import load_mission
from companion.planning.coordination.plan import plan_coordinated
from companion.planning.flight.forecast import first_forecast, mission_certificate
from companion.planning.routes import plan_routes
from companion.bench.machine import machine_line

REFERENCE = Path(__file__).resolve().parents[1] / "missions" / "paper_reference.yaml"


def measure(fn: Callable[[], object], repeats: int) -> tuple[float, float, object]:
    """(median wall s, median CPU s, last result); every repeat starts cold (no shared memo)."""
    wall, cpu, result = [], [], None
    for _ in range(repeats):
        w, c = time.perf_counter(), time.process_time()
        result = fn()
        wall.append(time.perf_counter() - w)
        cpu.append(time.process_time() - c)
    return statistics.median(wall), statistics.median(cpu), result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--scenarios", type=int, default=0)
    parser.add_argument("--seed", type=int, default=99)
    args = parser.parse_args()
    print(machine_line(), flush=True)
    if args.scenarios:
        random_scenarios(args.seed, args.scenarios)
        return
    mission = load_mission(REFERENCE)
    routes = plan_routes(mission)
    held = replace(mission, coordination=replace(mission.coordination, hold_s_max=200.0))
    cases = [
        ("plan, paper's rule (a never waits)", lambda: plan_coordinated(mission, routes, first_forecast(mission, routes))),
        ("plan, a may hold 200 s (hold search + plan)", lambda: plan_coordinated(held, routes, first_forecast(held, routes))),
        ("plan, a holds 162 s (given)", lambda: plan_coordinated(held, routes, first_forecast(held, routes), hold_s=161.55494421403512)),
        ("occlusion certificate", lambda: mission_certificate(mission, routes)),
    ]
    print(f"reference mission, 10 m cells, median of {args.repeats}")
    for label, fn in cases:
        wall, cpu, result = measure(fn, args.repeats)
        detail = (f"hold {result.hold_s:.0f} s, b: {result.blocking['b'].value}, arrives {result.timed['b'].arrival_s:.0f} s"
                  if hasattr(result, "timed") else result.describe().replace("\n", ";"))
        print(f"{label:46} wall {wall:6.2f} s  cpu {cpu:6.2f} s  ({detail})")


def random_scenarios(seed: int, n: int) -> None:
    from companion.scenarios import generate_scenario
    verdicts: dict[str, int] = {}
    for i in range(n):
        mission = generate_scenario(seed, i).mission
        routes = plan_routes(mission)
        _, cert_cpu, cert = measure(lambda: mission_certificate(mission, routes), 1)
        held = replace(mission, coordination=replace(mission.coordination, hold_s_max=300.0))
        _, plan_cpu, plan = measure(lambda: plan_coordinated(held, routes, first_forecast(held, routes)), 1)
        verdicts[cert.verdict] = verdicts.get(cert.verdict, 0) + 1
        lower = mission.by_priority[1].name
        print(f"seed {seed} #{i}: closest approach {cert.verdict} (least hold {cert.closest_approach_min_hold_s}), "
              f"whole flight least hold {cert.whole_flight_min_hold_s}; certificate {cert_cpu:.2f} s CPU; "
              f"plan (hold <= 300 s) {plan_cpu:.2f} s CPU: hold {plan.hold_s:.0f} s, {lower} {plan.blocking[lower].value}")
    print(verdicts)


if __name__ == "__main__":
    main()
