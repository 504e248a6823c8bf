"""One plant step: the multicopter against the paper's unicycle, interleaved. Prints medians.

    python benchmarks/bench_plant.py [--repeat N] [--calls N]

Each round flies the same turning body command (10 m/s, 19.1 deg/s) through ``--calls`` steps of
each plant, at the headless runner's 0.5 s step (5 substeps for the multicopter) and the stub's
20 ms step, alternating the plants so that load on a shared machine hits both alike.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

from uav_model.plant import KinematicState, Plant, VelocityCommand, VelocityFrame, limits_for, step_for
from companion.bench.machine import machine_line

TURN = VelocityCommand(VelocityFrame.BODY_NED, 10.0, 0.0, 0.0, math.radians(-19.1))


def _us_per_call(plant: Plant, dt_s: float, calls: int) -> float:
    step = step_for(plant)
    limits = limits_for(plant, speed_m_s=10.0, max_yaw_rate_rad_s=10.0 / 30.0, max_accel_m_s2=8.0)
    state = KinematicState(0.0, 0.0, -50.0)
    t0 = time.perf_counter()
    for _ in range(calls):
        state = step(state, TURN, limits, dt_s)
    return (time.perf_counter() - t0) / calls * 1e6


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=15)
    ap.add_argument("--calls", type=int, default=5000)
    args = ap.parse_args(argv)
    print(machine_line(), flush=True)
    cases = [(p, dt) for dt in (0.5, 0.02) for p in (Plant.UNICYCLE, Plant.MULTICOPTER)]
    times: dict[tuple[Plant, float], list[float]] = {c: [] for c in cases}
    for _ in range(args.repeat):
        for case in cases:
            times[case].append(_us_per_call(*case, args.calls))
    print(f"plant step, us per call (median of {args.repeat} x {args.calls} calls, interleaved)")
    for dt in (0.5, 0.02):
        uni, multi = (statistics.median(times[(p, dt)]) for p in (Plant.UNICYCLE, Plant.MULTICOPTER))
        print(f"  dt {dt:>4} s: unicycle {uni:6.2f}   multicopter {multi:6.2f}   ratio {multi / uni:4.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
