"""The reference mission flown by astar-bdwa-timed with a timed route that holds UAV a at its
station before departure (with a departing at t = 0, keeping the sight line blocked at
closest approach is impossible whatever b does: the occlusion certificate says so). Prints, per hold, the sight line blocked
fraction, whether it is blocked at closest approach, both flight times against the bound and the
planner's ms per tick.

    python benchmarks/bench_timed_hold.py [HOLD_S ...]     (default: 0 75 150)

Rows "given": only a carries a schedule (the given hold), b flies its speed window freely. Row
"planned": the runner's default, the coordinated space-time plan for both (``plan_coordinated``)
with ``coordination.hold_s_max`` = 200 s, which picks a's hold itself.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from companion.planning.routes import plan_routes
from companion.planning.flight.headless import simulate
from companion.planning.coordination.timed import forecast
from uav_model.mission import load_mission
from companion.bench.machine import machine_line

REFERENCE = Path(__file__).resolve().parents[1] / "missions" / "paper_reference.yaml"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("holds", nargs="*", type=float, default=[0.0, 75.0, 150.0])
    args = parser.parse_args()
    print(machine_line(), flush=True)
    mission = load_mission(REFERENCE)
    routes = plan_routes(mission)
    a = mission.by_priority[0]
    print("hold_s          blocked  crossing  a_s (from t=0)  b_s    bound_s  ms/tick a / b  success")
    for hold in args.holds:
        timed = {a.name: forecast(a.name, routes[a.name].sparse_enu_m, a.speed_m_s, hold_s=hold)}
        _row(f"{hold:6.0f} given", simulate(mission, "astar-bdwa-timed", routes=routes, timed_routes=timed).summary)
    held = dataclasses.replace(mission, coordination=dataclasses.replace(mission.coordination, hold_s_max=200.0))
    _row("planned (<= 200)", simulate(held, "astar-bdwa-timed", routes=routes).summary)


def _row(label: str, s) -> None:
    va, vb = s.vehicles["a"], s.vehicles["b"]
    print(f"{label:16}  {100 * s.los_blocked_fraction:5.1f} %  {'blocked' if s.crossing_occluded else 'open':8}  "
          f"{va.flight_time_s:14.1f}  {vb.flight_time_s:5.1f}  {vb.lower_bound_s:7.1f}  "
          f"{va.planner_ms_per_tick:.2f} / {vb.planner_ms_per_tick:.2f}  {s.success}")


if __name__ == "__main__":
    main()
