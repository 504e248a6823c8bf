"""``companion run`` end to end against the embedded stub: wall time and flight times vs simulate.

Runs the real command (a child process, real UDP, MAVSDK) ``--repeats`` times and prints the
median wall time of the whole run (connect, upload, take-off, flight, landing), each vehicle's
flight time beside ``companion simulate``'s, and the offboard re-entries the stub forced. No
pass/fail. Target: the reference mission at 20x in <= 60 s wall, flight times within 3 % of
simulate.

    python benchmarks/bench_companion_run.py [--mission M] [--speedup 20] [--repeats 3]
                                             [--loss P --latency-ms MS]
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

from uav_model.mission import load_mission
from companion.planning.flight.headless import simulate
from sim_bridge.testing import free_udp_port_block, free_udp_ports
from companion.bench.machine import machine_line

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--mission", type=Path, default=ROOT / "missions" / "paper_reference.yaml")
    p.add_argument("--speedup", type=float, default=20.0)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--loss", type=float, default=0.0)
    p.add_argument("--latency-ms", type=float, default=0.0)
    args = p.parse_args()
    print(machine_line(), flush=True)

    mission = load_mission(args.mission)
    headless = simulate(mission).summary
    walls, per_vehicle, reentries, ok = [], {v.name: [] for v in mission.vehicles}, [], 0
    for i in range(args.repeats):
        with tempfile.TemporaryDirectory() as tmp:
            cmd = [sys.executable, "-m", "companion", "run", str(args.mission), "--speedup", f"{args.speedup:g}",
                   "--out", tmp, "--port-base", str(free_udp_port_block(len(mission.vehicles))),
                   "--gcs-port", str(free_udp_ports(1)[0]), "--seed", str(i)]
            if args.loss:
                cmd += ["--loss", f"{args.loss:g}"]
            if args.latency_ms:
                cmd += ["--latency-ms", f"{args.latency_ms:g}"]
            t0 = time.perf_counter()
            code = subprocess.run(cmd, capture_output=True, text=True, timeout=600).returncode
            walls.append(time.perf_counter() - t0)
            summary = json.loads((Path(tmp) / "summary.json").read_text())
        ok += code == 0
        for name, v in summary["vehicles"].items():
            per_vehicle[name].append(v["flight_time_s"])
        reentries.append(sum(v["offboard_reentries"] for v in summary["live"]["vehicles"].values()))
        print(f"run {i + 1}: exit {code}, wall {walls[-1]:.1f} s, "
              + ", ".join(f"{n} {v['flight_time_s']:.1f} s" for n, v in summary["vehicles"].items())
              + f", offboard re-entries {reentries[-1]}", flush=True)

    print(f"\n{args.mission.name} at {args.speedup:g}x, loss {args.loss:g}, latency {args.latency_ms:g} ms: "
          f"{ok}/{args.repeats} succeeded")
    print(f"wall time per run: median {statistics.median(walls):.1f} s (min {min(walls):.1f}, max {max(walls):.1f})")
    for name, times in per_vehicle.items():
        ref = headless.vehicles[name].flight_time_s
        med = statistics.median(times)
        print(f"vehicle {name}: flight time median {med:.1f} s vs simulate {ref:.1f} s ({100 * (med / ref - 1):+.2f} %)")
    print(f"offboard re-entries per run: median {statistics.median(reentries):g}")


if __name__ == "__main__":
    main()
