"""``companion run`` with a fleet: CPU per vehicle and the achieved speed factor.

Runs the real command (a child process; the embedded stub is its child; real UDP, one MAVSDK
System per vehicle on ports 14540+i) ``--repeats`` times against the 8-vehicle mission at
``--speedup`` and prints, as medians over the runs:

- the CPU seconds of the companion process and of the stub process (psutil, sampled every
  0.2 s wall; the last sample before exit is kept, so a few tenths of a second may be missed)
  and their sum per vehicle, per simulated second and as a share of one core;
- the achieved speed factor: the mission's simulated seconds over its wall seconds (the
  summary's ``speed_factor``), and the whole run's (connect to landing) sim / wall.

No pass/fail: on a shared machine the figures move with the load; quote medians.

    python benchmarks/bench_fleet.py [--mission missions/eight_vehicles.yaml] [--speedup 20] [--repeats 3]
                                     [--telemetry-hz 10]
    python benchmarks/bench_fleet.py --mission missions/ring16.yaml --speedup 8 --telemetry-hz 5
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import psutil

from sim_bridge.testing import free_udp_port_block, free_udp_ports
from uav_model.mission import load_mission
from companion.bench.machine import machine_line

ROOT = Path(__file__).resolve().parents[1]


def _cpu_s(proc: psutil.Process) -> float:
    t = proc.cpu_times()
    return t.user + t.system  # not children_*: the stub, once reaped, would count twice


def run_once(mission: Path, speedup: float, count: int, seed: int, telemetry_hz: float) -> dict[str, float]:
    """One ``companion run``; CPU seconds of the companion and the stub, wall and sim seconds."""
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "companion", "run", str(mission), "--speedup", f"{speedup:g}",
               "--out", tmp, "--port-base", str(free_udp_port_block(count)), "--gcs-port", str(free_udp_ports(1)[0]),
               "--seed", str(seed), "--progress-every", "1000", "--telemetry-hz", f"{telemetry_hz:g}"]
        started = time.perf_counter()
        child = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        proc = psutil.Process(child.pid)
        cpu: dict[int, float] = {}
        while child.poll() is None:
            try:
                procs = [proc, *proc.children(recursive=True)]
                for p in procs:
                    with p.oneshot():
                        cpu[p.pid] = _cpu_s(p)
            except psutil.Error:  # exiting between the listing and the read
                pass
            time.sleep(0.2)
        wall = time.perf_counter() - started
        summary = json.loads((Path(tmp) / "summary.json").read_text())
    companion = cpu.get(child.pid, 0.0)
    stub = sum(v for pid, v in cpu.items() if pid != child.pid)
    return {"exit": child.returncode, "success": summary["success"], "companion_cpu_s": companion,
            "stub_cpu_s": stub, "wall_s": wall, "sim_s": summary["duration_s"],
            "speed_factor": summary.get("speed_factor") or 0.0, "reason": summary.get("reason"),
            "min_separation_m": summary.get("min_separation_m") or 0.0,
            "reentries": sum(v["offboard_reentries"] for v in summary["live"]["vehicles"].values())}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--mission", type=Path, default=ROOT / "missions" / "eight_vehicles.yaml")
    p.add_argument("--speedup", type=float, default=20.0)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--telemetry-hz", type=float, default=10.0, help="companion run --telemetry-hz")
    args = p.parse_args()
    print(machine_line(), flush=True)
    count = len(load_mission(args.mission).vehicles)
    runs = []
    for i in range(args.repeats):
        r = run_once(args.mission, args.speedup, count, i, args.telemetry_hz)
        runs.append(r)
        print(f"run {i + 1}: exit {r['exit']}, success {r['success']} ({r['reason'] or 'ok'}), "
              f"min separation {r['min_separation_m']:.1f} m, wall {r['wall_s']:.1f} s, "
              f"sim {r['sim_s']:.1f} s, speed factor {r['speed_factor']:.1f}x, companion CPU {r['companion_cpu_s']:.1f} s, "
              f"stub CPU {r['stub_cpu_s']:.1f} s, offboard re-entries {r['reentries']}", flush=True)

    def med(key: str) -> float:
        return statistics.median(r[key] for r in runs)

    total = med("companion_cpu_s") + med("stub_cpu_s")
    print(f"\n{args.mission.name}: {count} vehicles at {args.speedup:g}x, telemetry {args.telemetry_hz:g} Hz, "
          f"{sum(r['success'] for r in runs)}/"
          f"{len(runs)} succeeded (medians over {len(runs)} runs)")
    print(f"achieved speed factor: {med('speed_factor'):.1f}x (mission sim s / wall s); "
          f"whole run {statistics.median(r['sim_s'] / r['wall_s'] for r in runs):.1f}x incl. connect and landing")
    print(f"CPU: companion {med('companion_cpu_s'):.1f} s + stub {med('stub_cpu_s'):.1f} s = {total:.1f} s per run; "
          f"{total / count:.1f} s per vehicle ({med('companion_cpu_s') / count:.2f} companion + "
          f"{med('stub_cpu_s') / count:.2f} stub)")
    per_core = statistics.median((r['companion_cpu_s'] + r['stub_cpu_s']) / r['wall_s'] / count for r in runs)
    print(f"per vehicle: {100 * per_core:.1f} % of one core; "
          f"{1e3 * statistics.median((r['companion_cpu_s'] + r['stub_cpu_s']) / r['sim_s'] / count for r in runs):.1f} "
          f"ms CPU per simulated second")


if __name__ == "__main__":
    main()
