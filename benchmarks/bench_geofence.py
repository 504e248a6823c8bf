"""Cost of the stub's geofence: one SimVehicle physics step with and without the companion's fence.

The fence is the one ``companion run`` uploads (``companion.app.fence.mission_fence``: the area as
an inclusion polygon, every static obstacle inflated as an exclusion), stored through the
vehicle's own mission protocol. Runs alternate fenced and unfenced vehicles; prints medians.

    python benchmarks/bench_geofence.py [--runs 9] [--steps 2000] [MISSION.yaml ...]
"""

from __future__ import annotations

import argparse
import statistics
import timeit

from pymavlink.dialects.v20 import common as mavlink

from companion.app.fence import mission_fence
from companion.vehicle.convert import MAV_FRAME_GLOBAL, fence_items
from uav_model.mission import load_mission
from sim_bridge.testing import GcsCodec, boot
from sim_bridge.vehicle import SimVehicle
from companion.bench.machine import machine_line

FENCE = mavlink.MAV_MISSION_TYPE_FENCE


def vehicle(mission, fenced: bool, gcs: GcsCodec) -> SimVehicle:
    v = SimVehicle(mission.vehicles[0], mission)
    v.add_link("api")
    boot(v)
    if fenced:
        items = fence_items(mission_fence(mission))
        v.handle(gcs.wire(gcs.enc.mission_count_encode(v.system_id, 1, len(items), FENCE)), "api")
        for i, it in enumerate(items):
            v.handle(gcs.wire(gcs.enc.mission_item_int_encode(v.system_id, 1, i, MAV_FRAME_GLOBAL, it.command, 0, 1,
                                                              it.param1, 0, 0, 0, it.lat_e7, it.lon_e7, 0, FENCE)), "api")
        assert len(v.missions.plan(FENCE)) == len(items)
    return v


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("missions", nargs="*", default=["missions/paper_reference.yaml", "missions/moving_obstacles.yaml"])
    ap.add_argument("--runs", type=int, default=9)
    ap.add_argument("--steps", type=int, default=2000)
    args = ap.parse_args()
    print(machine_line(), flush=True)
    gcs = GcsCodec()
    for path in args.missions:
        mission = load_mission(path)
        us: dict[bool, list[float]] = {True: [], False: []}
        for _ in range(args.runs):
            for fenced in (True, False):
                v = vehicle(mission, fenced, gcs)
                us[fenced].append(timeit.timeit(lambda: v.step(0.02), number=args.steps) / args.steps * 1e6)
        items = len(fence_items(mission_fence(mission)))
        print(f"{path}: fence of {items} items: {statistics.median(us[True]):.1f} us/step, "
              f"without: {statistics.median(us[False]):.1f} us/step (medians of {args.runs})")


if __name__ == "__main__":
    main()
