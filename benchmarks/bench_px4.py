"""Flights on real PX4 SITL beside the stub and ``simulate``: wall and CPU seconds, flight times.

For each mission, one ``companion run --sim px4`` (PX4 SIH, one instance per vehicle) and one
``companion run`` on the embedded stub, both at ``--speedup``, and ``companion simulate`` on the
mission's plant and on the multicopter plant. CPU is the run's and all its children's (PX4, the
stub, MAVSDK servers), user + system. Prints a table; no pass/fail.

PX4's ports are fixed (14540 + i, 14550): run it where nothing else flies, e.g.

    unshare -mn sh -c 'ip link set lo up; mount -t tmpfs tmpfs /tmp; \\
        PX4_SITL_DIR=../shared/px4-sih/sitl .venv/bin/python benchmarks/bench_px4.py'

    python benchmarks/bench_px4.py [--missions M ...] [--variant V] [--speedup 4] [--px4-dir DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from companion.cli.errors import BadInput
from companion.cli.options import with_plant
from companion.planning.flight.headless import simulate
from companion.sitl.px4 import PX4_DIR_ENV, find_px4
from uav_model.mission import load_mission

ROOT = Path(__file__).resolve().parents[1]
MISSIONS = (ROOT / "missions" / "paper_reference.yaml", ROOT / "missions" / "small_reference.yaml")


def _children_cpu_s() -> float:
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def fly(mission: Path, sim_args: list[str], variant: str | None, timeout_s: float) -> dict:
    """One ``companion run``: exit code, wall and CPU seconds, and each vehicle's flight time."""
    with tempfile.TemporaryDirectory() as out:
        cmd = [sys.executable, "-m", "companion", "run", str(mission), *sim_args, "--out", out]
        cmd += ["--variant", variant] if variant else []
        cpu0, t0 = _children_cpu_s(), time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
        wall, cpu = time.perf_counter() - t0, _children_cpu_s() - cpu0
        path = Path(out) / "summary.json"
        summary = json.loads(path.read_text()) if path.exists() else {"vehicles": {}, "success": False}
    if proc.returncode != 0:  # why: the run's own last lines (its output folder is gone with the temp dir)
        why = [line for line in proc.stdout.splitlines() if line.startswith(("run:", "why:", "failsafe:"))]
        print(f"  {' '.join(sim_args[:2])}: exit {proc.returncode}: {' | '.join(why)} {proc.stderr.strip()[-300:]}",
              file=sys.stderr, flush=True)
    return {"exit": proc.returncode, "wall_s": wall, "cpu_s": cpu, "success": summary.get("success"),
            "times": {n: v["flight_time_s"] for n, v in summary["vehicles"].items()}}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--missions", type=Path, nargs="+", default=list(MISSIONS))
    p.add_argument("--variant", default=None, help="planner variant (default: the mission's)")
    p.add_argument("--speedup", type=float, default=4.0, help="PX4 and the stub (default 4)")
    p.add_argument("--px4-dir", default=None, help=f"PX4 SITL build (default: ${PX4_DIR_ENV})")
    p.add_argument("--timeout", type=float, default=900.0, help="wall seconds per run")
    args = p.parse_args()
    try:
        px4_dir = find_px4(args.px4_dir)
    except BadInput as exc:
        sys.exit(f"bench_px4: {exc}")
    print(f"speedup {args.speedup:g}x, PX4 from {px4_dir}, {os.cpu_count()} CPUs, "
          f"load {os.getloadavg()[0]:.1f} at the start")
    print(f"{'mission':16} {'run':22} {'exit':>4} {'wall_s':>7} {'cpu_s':>7}  flight times (s)")
    for mission_path in args.missions:
        mission = load_mission(mission_path)
        name = mission.name
        for m in {p: with_plant(mission, p) for p in (mission.plant.value, "multicopter")}.values():  # each plant once
            t0, c0 = time.perf_counter(), time.process_time()
            run = simulate(m, args.variant)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            times = "  ".join(f"{n} {v.flight_time_s:.1f}" for n, v in run.summary.vehicles.items())
            print(f"{name:16} {'simulate ' + m.plant.value:22} {0 if run.success else 1:>4} {wall:7.1f} {cpu:7.1f}  "
                  f"{times}", flush=True)
        for label, sim_args in (("stub", ["--speedup", f"{args.speedup:g}"]),
                                ("px4", ["--sim", "px4", "--px4-dir", str(px4_dir),
                                         "--speedup", f"{args.speedup:g}"])):
            r = fly(mission_path, sim_args, args.variant, args.timeout)
            times = "  ".join(f"{n} {t:.1f}" for n, t in r["times"].items())
            print(f"{name:16} {label + ' (companion run)':22} {r['exit']:>4} {r['wall_s']:7.1f} {r['cpu_s']:7.1f}  "
                  f"{times}", flush=True)


if __name__ == "__main__":
    main()
