"""How long ``companion validate`` takes, and how much memory, against the mission's size.

Each row is a fresh ``companion validate`` process on a generated mission (two vehicles at
opposite corners of a square, ``obstacles`` regular polygons of ``vertices`` corners each on a
lattice between them), timed from outside: wall and CPU seconds and peak RSS (``ru_maxrss`` of the children so far).
The certificate runs with its default budget, so a row that hits it says "undecided".

    PYTHONPATH=$PWD python benchmarks/bench_validate.py                 # obstacles 10..200 x vertices 4..256
    PYTHONPATH=$PWD python benchmarks/bench_validate.py --obstacles 10 200 --vertices 8
"""

from __future__ import annotations

import argparse
import math
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

OBSTACLES = (10, 50, 100, 200)
VERTICES = (4, 16, 64, 256)


def sized_mission(obstacles: int, vertices: int, *, side_m: float = 6000.0) -> str:
    """Mission YAML with ``obstacles`` regular ``vertices``-gons on a lattice inside a square of
    ``side_m``, clear of both stations (at opposite corners), every one a valid polygon."""
    per_row = math.ceil(math.sqrt(obstacles))
    pitch = (side_m - 1200.0) / per_row
    radius = 0.3 * pitch
    lines = ["name: sized", f"area: {{x_min_m: 0, y_min_m: 0, x_max_m: {side_m:g}, y_max_m: {side_m:g}}}",
             "stations:", "  A: [0, 0]", f"  B: [{side_m:g}, {side_m:g}]", "obstacles:"]
    for i in range(obstacles):
        cx = 600.0 + pitch * (i % per_row + 0.5)
        cy = 600.0 + pitch * (i // per_row + 0.5)
        ring = ", ".join(f"[{cx + radius * math.cos(2 * math.pi * k / vertices + 0.1):.2f}, "
                         f"{cy + radius * math.sin(2 * math.pi * k / vertices + 0.1):.2f}]" for k in range(vertices))
        lines.append(f"  - {{id: p{i}, shape: polygon, vertices: [{ring}]}}")
    lines += ["vehicles:", "  - {name: a, start: A, goal: B}", "  - {name: b, start: B, goal: A}",
              "planner: {grid_resolution_m: 20}"]
    return "\n".join(lines) + "\n"


def measure(path: Path, extra: list[str]) -> tuple[float, float, float, int, str]:
    """(wall s, CPU s, peak RSS MiB, exit code, last stdout or stderr line) of one validate process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    env = {**os.environ, "PYTHONPATH": os.environ.get("PYTHONPATH", str(Path(__file__).resolve().parents[1]))}
    started = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "companion", "validate", str(path), *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    out, err = proc.communicate()
    wall = time.perf_counter() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    peak = after.ru_maxrss / 1024.0  # the largest child so far: rows go from small to large
    lines = [ln for ln in (out + err).splitlines() if ln.strip()]
    return wall, cpu, peak, proc.returncode, (lines[-1].strip() if lines else "")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--obstacles", type=int, nargs="+", default=list(OBSTACLES))
    parser.add_argument("--vertices", type=int, nargs="+", default=list(VERTICES))
    parser.add_argument("--no-certificate", action="store_true", help="pass --no-certificate to validate")
    args = parser.parse_args()
    extra = ["--no-certificate"] if args.no_certificate else []
    print(f"{'obstacles':>9} {'vertices':>8} {'bytes':>9} {'wall_s':>7} {'cpu_s':>6} {'peak_MiB':>8} {'exit':>4}  last line")
    with tempfile.TemporaryDirectory() as tmp:
        for n in args.obstacles:
            for v in args.vertices:
                path = Path(tmp) / f"m{n}x{v}.yaml"
                path.write_text(sized_mission(n, v), encoding="utf-8")
                wall, cpu, peak, code, last = measure(path, extra)
                print(f"{n:>9} {v:>8} {path.stat().st_size:>9} {wall:>7.2f} {cpu:>6.2f} {peak:>8.0f} {code:>4}  "
                      f"{last[:80]}", flush=True)


if __name__ == "__main__":
    main()
