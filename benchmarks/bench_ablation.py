"""How long does `companion bench` take, and where does the time go?

    python benchmarks/bench_ablation.py [--scenarios 12] [--seed 7] [--workers 2] [--repeats 3]
                                        [--numpy-too] [--baseline DIR]

Runs a slice of the ablation (all four variants) and prints, per repeat and as medians: wall
time, CPU time (the run and its workers, without the interpreter's start and imports), simulated vehicle-ticks, CPU ms per vehicle-tick, and
the 120 x 4 wall time that CPU cost extrapolates to on ``--workers`` otherwise idle cores, and
this tree's CPU per vehicle-tick over each other kind's, repeat by repeat (median). CPU
per tick is the number to compare across machines and loads: wall time on a shared 2-core box
mostly measures the neighbours, and the CPU model (printed first) decides the rest. Targets: 120 x
4 in <= 60 s on 2 cores, <= 0.1 ms per vehicle-tick.

Every repeat runs in a fresh process, one per kind of code, alternately (old and new in one
window, as the shared machine's speed drifts):

- this tree with whatever is installed (numba's compiled paths when the ``fast`` extra is);
- ``--numpy-too``: this tree without the compiled paths (the DWA kernels, the sight shadows and
  the multicopter's substeps as numpy / Python: the code without numba);
- ``--baseline DIR``: another tree of the project (e.g. ``git archive main | tar -x -C DIR``).
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

# Runs in the child: a slice of the bench, then its vehicle-ticks as JSON on the last line.
_CHILD = """
import json, sys
seed, count, workers, numpy_only = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]), sys.argv[4] == "1"
if numpy_only:
    sys.modules["numba"] = None  # before any import: the DWA's backend is chosen when its configs are built
    from companion.planning.coordination import shadow
    from uav_model.plant import multicopter
    shadow._blocked_jit = None
    multicopter._substep_loop = multicopter.substep_loop_python
import resource, time
try:
    from companion.bench.table import DEFAULT_VARIANTS
except ImportError:  # a --baseline tree from before the CLI package
    from companion.bench.table import DEFAULT_VARIANTS
from companion.bench.execute import run_bench
def cpu():
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime
cpu0, wall0 = cpu(), time.perf_counter()
rows = run_bench(seed, count, DEFAULT_VARIANTS, workers=workers, progress=None)
wall, spent = time.perf_counter() - wall0, cpu() - cpu0
# Each vehicle ticks until it arrives or the run ends: its flight time / dt (0.5 s).
ticks = sum((r.get(f"{n}_flight_time_s") or 0.0) / 0.5 for r in rows for n in ("a", "b"))
print(json.dumps({"runs": len(rows), "ticks": ticks, "wall": wall, "cpu": spent}))
"""


def _repeat(tree: Path, numpy_only: bool, args: argparse.Namespace) -> tuple[float, float, dict]:
    """One slice in a fresh process: its wall and CPU seconds around run_bench (the interpreter's
    start and the imports left out; with workers, their start is in), and its counts."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    done = subprocess.run([sys.executable, "-c", _CHILD, str(args.seed), str(args.scenarios), str(args.workers),
                           "1" if numpy_only else "0"], env=env, cwd=tree, capture_output=True, text=True)
    if done.returncode:
        sys.exit(f"bench_ablation: the run in {tree} failed:\n{done.stderr[-2000:]}")
    out = json.loads(done.stdout.strip().splitlines()[-1])
    return out["wall"], out["cpu"], out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", type=int, default=12)
    parser.add_argument("--seed", type=int, default=7, help="a tuning seed, not a reporting one")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--numpy-too", action="store_true", help="also time this tree without numba's paths")
    parser.add_argument("--baseline", type=Path, default=None, metavar="DIR", help="also time the tree in DIR")
    args = parser.parse_args()
    print(machine_line(), flush=True)
    if args.baseline is not None and not (args.baseline / "companion").is_dir():
        sys.exit(f"bench_ablation: --baseline {args.baseline} is not a tree of the project")

    kinds = {"this tree": (ROOT, False)}
    if args.numpy_too:
        kinds["this tree, numpy"] = (ROOT, True)
    if args.baseline is not None:
        kinds[f"baseline {args.baseline}"] = (args.baseline.resolve(), False)
    walls, cpus, per_tick = ({k: [] for k in kinds} for _ in range(3))
    for k in range(args.repeats):
        for kind, (tree, numpy_only) in kinds.items():
            wall, cpu, out = _repeat(tree, numpy_only, args)
            walls[kind].append(wall)
            cpus[kind].append(cpu)
            per_tick[kind].append(1e3 * cpu / out["ticks"])
            print(f"repeat {k + 1} {kind}: {out['runs']} runs, wall {wall:.1f} s, cpu {cpu:.1f} s, "
                  f"{out['ticks']:.0f} vehicle-ticks, {per_tick[kind][-1]:.3f} cpu ms/vehicle-tick", flush=True)
    scale = 120 / args.scenarios
    for kind in kinds:
        cpu = statistics.median(cpus[kind])
        print(f"median {kind}: wall {statistics.median(walls[kind]):.1f} s, cpu {cpu:.1f} s, "
              f"{statistics.median(per_tick[kind]):.3f} cpu ms/vehicle-tick; extrapolated 120 x 4 on "
              f"{args.workers} idle cores: {cpu * scale / args.workers:.0f} s wall (target <= 60 s)")
    # The number to quote on a shared machine: this tree's CPU per vehicle-tick over the other
    # kind's of the same repeat (run back to back), as a median over the repeats.
    for kind in list(kinds)[1:]:
        ratios = [new / old for new, old in zip(per_tick["this tree"], per_tick[kind])]
        print(f"this tree / {kind}, cpu per vehicle-tick: median {statistics.median(ratios):.3f} "
              f"(repeats {', '.join(f'{r:.3f}' for r in ratios)})")


if __name__ == "__main__":
    main()
