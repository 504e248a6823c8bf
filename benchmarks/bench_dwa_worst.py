"""The BDWA tick's worst cases: how its CPU grows with the obstacles within reach, and a boxed-in
tick (no legal rollout). Prints the CPU model first, then medians.

    python benchmarks/bench_dwa_worst.py [--rounds 7] [--calls 20]

The paper's window (31 yaw rates x 22 steps, p = 11 s, the multicopter's lag) at (1500, 1500):

- "ring N": N circles (radius 8 m) 60-110 m from the vehicle, as compare_peers.py places them:
  within one rollout's reach, so culling keeps them all. From about 100 of them no rollout is
  legal and the tick recovers (spin recovery, hold or escape): the per-obstacle cost is the
  tick's CPU over the empty tick's, per obstacle, so it counts the recovery's own cost (placing and
  checking the spin headings, much the same at any count) against the obstacles too;
- "spread N": N small circles (radius 2 m) over the 130 m around the vehicle: some rollouts stay
  legal up to 200 of them (the cost of the tick itself per obstacle);
- "boxed in": a closed ring of 40 circles 30 m out and 160 more beyond: every rollout and every
  spin-recovery heading is blocked, the vehicle holds.

Each case runs on the compiled backend (numba, when installed) and on the numpy backend, in
alternating rounds; a figure is the median over rounds of the CPU per call
(``time.process_time``). Targets: the boxed-in tick <= 5 ms; the per-obstacle cost flat up to
200 obstacles. To compare two versions, run it from each tree in turn, several times, and
compare medians.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import statistics
import time

import numpy as np

from companion.bench.machine import machine_line
from companion.planning.dwa import NoLegalRollout, OtherUav, Pose, plan_step
from companion.planning.dwa.backend import COMPILED, NUMPY
from companion.planning.obstacle_field import ObstacleField
from companion.planning.vehicle_planner import VehiclePlanner
from uav_model.mission import parse_mission

WORLD = """
area: {x_min_m: 0, y_min_m: 0, x_max_m: 3000, y_max_m: 3000}
stations: {A: [100, 100], B: [2900, 2900]}
vehicles:
  - {name: a, start: A, goal: B, initial_heading_deg: 45}
  - {name: b, start: B, goal: A, initial_heading_deg: -135}
"""
POSE = Pose(1500.0, 1500.0, 0.3)
GOAL = (2900.0, 2900.0)
OTHER = OtherUav(2900.0, 2900.0, 0.0, 0.0)  # far away: no sightline or separation work to speak of
COUNTS = (0, 50, 100, 200)


def ring(count: int, seed: int = 7) -> np.ndarray:
    """``count`` centres 60-110 m from the pose (compare_peers.py's DWA scene)."""
    rng = np.random.default_rng(seed)
    radius, angle = rng.uniform(60.0, 110.0, count), rng.uniform(-math.pi, math.pi, count)
    return np.column_stack([POSE.x_m + radius * np.cos(angle), POSE.y_m + radius * np.sin(angle)])


def spread(count: int, seed: int = 7) -> np.ndarray:
    """``count`` centres spread evenly over the disc of 130 m around the pose (none on it)."""
    rng = np.random.default_rng(seed)
    radius, angle = 130.0 * np.sqrt(rng.uniform(0.05, 1.0, count)), rng.uniform(-math.pi, math.pi, count)
    return np.column_stack([POSE.x_m + radius * np.cos(angle), POSE.y_m + radius * np.sin(angle)])


def boxed_in(count: int = 200) -> np.ndarray:
    """A closed ring of 40 centres 30 m out, and ``count`` - 40 of :func:`ring` beyond it."""
    angle = np.linspace(-math.pi, math.pi, 40, endpoint=False)
    inner = np.column_stack([POSE.x_m + 30.0 * np.cos(angle), POSE.y_m + 30.0 * np.sin(angle)])
    return np.vstack([inner, ring(count - 40)])


def tick(centres: np.ndarray, radius_m: float):
    """The tick among circles at ``centres``, and its config on each backend."""
    lines = "".join(f"  - {{id: c{i}, shape: circle, center: [{x:.1f}, {y:.1f}], radius_m: {radius_m}}}\n"
                    for i, (x, y) in enumerate(centres))
    mission = parse_mission(WORLD + ("obstacles:\n" + lines if len(centres) else ""), "bench_dwa_worst")
    config = VehiclePlanner.build(mission, mission.by_priority[0], None, "bdwa").config
    snapshot = ObstacleField.from_world(mission.world).at_time(0.0)
    backends = [b for b in (COMPILED, NUMPY) if b is not None]
    return snapshot, {b.name: dataclasses.replace(config, backend=b) for b in backends}


def cpu_ms(fn, calls: int) -> float:
    t0 = time.process_time()
    for _ in range(calls):
        fn()
    return (time.process_time() - t0) * 1e3 / calls


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--calls", type=int, default=20, help="calls per round and case")
    args = parser.parse_args()
    print(machine_line(), flush=True)
    cases = {f"ring {n}": tick(ring(n), 8.0) for n in COUNTS}
    cases.update({f"spread {n}": tick(spread(n), 2.0) for n in COUNTS if n})
    cases["boxed in (200)"] = tick(boxed_in(), 8.0)
    samples: dict[tuple[str, str], list[float]] = {}
    outcome: dict[str, str] = {}
    for name, (snapshot, configs) in cases.items():
        for kind, config in configs.items():
            result = plan_step(POSE, GOAL, OTHER, snapshot, config)  # loads the compiled code
            outcome[name] = ("no legal rollout: " + result.reason.split("; ")[-1].split(":")[0]
                             if isinstance(result, NoLegalRollout) else f"{result.legal_count} legal rollouts")
    for _ in range(args.rounds):
        for name, (snapshot, configs) in cases.items():
            for kind, config in configs.items():
                ms = cpu_ms(lambda: plan_step(POSE, GOAL, OTHER, snapshot, config), args.calls)
                samples.setdefault((name, kind), []).append(ms)
    median = {key: statistics.median(values) for key, values in samples.items()}
    kinds = list(next(iter(cases.values()))[1])
    print(f"CPU per tick, median of {args.rounds} rounds x {args.calls} calls (ms); per obstacle: over the empty tick")
    print(f"  {'case':16} {'outcome':34}" + "".join(f" {k + ' ms':>10} {k + ' us/obst':>14}" for k in kinds))
    for name in cases:
        count = int(name.split()[-1].strip("()"))
        row = f"  {name:16} {outcome[name]:34}"
        for kind in kinds:
            ms = median[(name, kind)]
            per = (ms - median[("ring 0", kind)]) * 1e3 / count if count else float("nan")
            row += f" {ms:10.3f} {per:14.2f}"
        print(row)


if __name__ == "__main__":
    main()
