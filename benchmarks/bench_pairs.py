"""Assigned sight-line pairs on the eight-vehicle ring around a hub (``companion.formations.ring``:
600 m ring, pairs v0-v4 and v2-v6, as ``missions/ring8_two_pairs.yaml`` with a 200 m hub), over
hub sizes, per variant: with the assignment, and with the same pairs only watched (no
``sightline`` section: the paper's pair is planned, v0-v4 and v2-v6 are read from the flight's
per-pair metrics). Prints per flight whether each line was blocked at its closest approach, the
blocked fraction, the least separation, the slowest flight against its bound, and each pair's
certificate (assigned only), then the totals.

    python benchmarks/bench_pairs.py [--hubs 140,150,...] [--variants astar-bdwa,astar-bdwa-timed]
"""

from __future__ import annotations

import argparse
import time

from companion.bench.machine import machine_line
from companion.formations import ring
from companion.planning.flight.headless import simulate_certified
from uav_model.mission import mission_from_data

PAIRS = [["v0", "v4"], ["v2", "v6"]]
NAMES = ("v0-v4", "v2-v6")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hubs", default=",".join(str(h) for h in range(140, 320, 10)))
    parser.add_argument("--variants", default="astar-bdwa,astar-bdwa-timed")
    args = parser.parse_args()
    print(machine_line(), flush=True)
    hubs = [float(h) for h in args.hubs.split(",")]
    totals: dict[tuple[str, str], list[int]] = {}
    print("variant            pairs     hub_m  success  v0-v4 / v2-v6 at closest (fraction)  min_sep_m  "
          "t/bound max  certificates  cpu_s")
    for variant in args.variants.split(","):
        for mode in ("assigned", "watched"):
            tally = totals.setdefault((variant, mode), [0, 0, 0])  # successes, lines blocked, flights
            for hub in hubs:
                doc = ring(8, 600.0, hub_m=hub, pairs=PAIRS if mode == "assigned" else None)
                mission = mission_from_data(doc, doc["name"]).with_variant(variant)
                started = time.process_time()
                run, certificates = simulate_certified(mission)
                cpu = time.process_time() - started
                s = run.summary
                lines = [s.pairs[p] for p in NAMES]
                ratio = max(v.ratio for v in s.vehicles.values() if v.ratio is not None)
                certs = " ".join(c.verdict for c in certificates) if mode == "assigned" else "-"
                print(f"{variant:18} {mode:9} {hub:6.0f}  {str(s.success):7}  "
                      f"{' / '.join('blocked' if p.crossing_occluded else 'open   ' for p in lines)} "
                      f"({' / '.join(f'{p.los_blocked_fraction:.2f}' for p in lines)})  "
                      f"{s.min_separation_m:9.1f}  {ratio:11.3f}  {certs:12}  {cpu:5.1f}", flush=True)
                tally[0] += bool(s.success)
                tally[1] += sum(p.crossing_occluded for p in lines)
                tally[2] += 1
    print()
    for (variant, mode), (ok, blocked, flights) in totals.items():
        print(f"{variant:18} {mode:9} success {ok}/{flights}, lines blocked at closest approach "
              f"{blocked}/{2 * flights}")


if __name__ == "__main__":
    main()
