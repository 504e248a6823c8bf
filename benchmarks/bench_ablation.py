"""How long does `companion bench` take, and where does the time go?

    python benchmarks/bench_ablation.py [--scenarios 12] [--seed 7] [--workers 2] [--repeats 3] [--numpy-too]

Runs a slice of the ablation (all four variants) and prints, per repeat and as medians: wall
time, CPU time (this process + workers), simulated vehicle-ticks, CPU ms per vehicle-tick, and
the 120 x 4 wall time that CPU cost extrapolates to on ``--workers`` otherwise idle cores. CPU
per tick is the number to compare across machines and loads: wall time on a shared 2-core box
mostly measures the neighbours. The target is 120 x 4 in <= 180 s on 2 cores (issue 15: <= 60 s,
and <= 0.1 ms per vehicle-tick).

``--numpy-too``: with numba installed, every repeat also runs on the numpy kernels (the code
without numba), alternately, in this process (``--workers`` is then ignored): old and new in
one window, CPU per vehicle-tick for both.
"""

from __future__ import annotations

import argparse
import contextlib
import resource
import statistics
import time

from companion.bench.cli import DEFAULT_VARIANTS
from companion.bench.execute import run_bench
from companion.planning.dwa import kernels


def _cpu_s() -> float:
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", type=int, default=12)
    parser.add_argument("--seed", type=int, default=7, help="a tuning seed, not a reporting one")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--numpy-too", action="store_true", help="also time the numpy kernels, alternately")
    args = parser.parse_args()

    kinds = {"": contextlib.nullcontext}
    if args.numpy_too and kernels.circle_clearance is not None:
        kinds = {"numba kernels": contextlib.nullcontext, "numpy kernels": kernels.numpy_only}
    workers = 1 if len(kinds) > 1 else args.workers
    walls, cpus, per_tick = ({k: [] for k in kinds} for _ in range(3))
    for k in range(args.repeats):
        for kind, context in kinds.items():
            with context():
                cpu0, wall0 = _cpu_s(), time.perf_counter()
                rows = run_bench(args.seed, args.scenarios, DEFAULT_VARIANTS, workers=workers, progress=None)
                wall, cpu = time.perf_counter() - wall0, _cpu_s() - cpu0
            # Each vehicle ticks until it arrives or the run ends: its flight time / dt (0.5 s).
            ticks = sum((r.get(f"{n}_flight_time_s") or 0.0) / 0.5 for r in rows for n in ("a", "b"))
            walls[kind].append(wall)
            cpus[kind].append(cpu)
            per_tick[kind].append(1e3 * cpu / ticks)
            print(f"repeat {k + 1} {kind}: {len(rows)} runs, wall {wall:.1f} s, cpu {cpu:.1f} s, "
                  f"{ticks:.0f} vehicle-ticks, {per_tick[kind][-1]:.3f} cpu ms/vehicle-tick")
    scale = 120 / args.scenarios
    for kind in kinds:
        cpu = statistics.median(cpus[kind])
        print(f"median {kind}: wall {statistics.median(walls[kind]):.1f} s, cpu {cpu:.1f} s, "
              f"{statistics.median(per_tick[kind]):.3f} cpu ms/vehicle-tick; extrapolated 120 x 4 on "
              f"{args.workers} idle cores: {cpu * scale / args.workers:.0f} s wall (target <= 60 s)")


if __name__ == "__main__":
    main()
