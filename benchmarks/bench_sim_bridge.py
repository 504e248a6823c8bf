"""Cost of the SITL stub: two vehicles at 20x with full telemetry and a flying MAVSDK client each.

The stub runs alone in a child process, which measures its own CPU (``time.process_time`` over
wall time) and the achieved speed factor; this process plays the companion: one MAVSDK
instance per vehicle, arm, take off, then offboard body-velocity setpoints every planner tick
(0.5 s of sim time) while subscribed to position telemetry, plus a GCS socket that drains the
GCS link. Target: under half of one core per vehicle. Prints medians over the runs.

    /tmp/venv/bin/python benchmarks/bench_sim_bridge.py [--runs 3] [--seconds 10] [--speedup 20]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import socket
import statistics
import sys
import time

from companion.bench.machine import machine_line

MISSION_YAML = """
name: bench
area: {x_min_m: 0, y_min_m: 0, x_max_m: 3000, y_max_m: 3000}
stations: {A: [100, 100], B: [2900, 2900]}
obstacles:
  - {id: fire, shape: circle, center: [1500, 1500], radius_m: 400}
  - {id: block, shape: rectangle, center: [800, 2200], width_m: 200, height_m: 300}
  - {id: m1, shape: circle, center: [500, 1500], radius_m: 100, motion: {type: shuttle, to: [1000, 2500], speed_m_s: 4}}
  - {id: m2, shape: circle, center: [2500, 500], radius_m: 120, motion: {type: shuttle, to: [2000, 1200], speed_m_s: 3}}
vehicles:
  - {name: a, start: A, goal: B, cruise_alt_m: 10}
  - {name: b, start: B, goal: A, cruise_alt_m: 10, initial_heading_deg: -135}
"""


def child(args: argparse.Namespace) -> None:
    """The stub alone: run for --seconds of wall time, then print its own cost as JSON."""
    from uav_model.mission import parse_mission
    from sim_bridge.bridge import SimBridge, SimOptions

    ports = json.loads(args.ports)

    async def main() -> dict:
        mission = parse_mission(MISSION_YAML, "bench.yaml")
        opts = SimOptions(speedup=args.speedup, api_ports=tuple(ports["api"]), gcs_port=ports["gcs"])
        async with SimBridge(mission, opts) as sim:
            await asyncio.sleep(args.warmup)
            cpu0, wall0, sim0 = time.process_time(), time.monotonic(), sim.sim_time_s
            tx0 = sim.stats["tx_messages"]
            await asyncio.sleep(args.seconds)
            cpu, wall = time.process_time() - cpu0, time.monotonic() - wall0
            return {"cpu_fraction": cpu / wall, "speedup": (sim.sim_time_s - sim0) / wall,
                    "tx_msg_s": (sim.stats["tx_messages"] - tx0) / wall, "rx_msg_s": sim.stats["rx_messages"] / wall,
                    "modes": [v.mode.name for v in sim.vehicles], "in_air": [v.in_air for v in sim.vehicles],
                    "offboard_losses": [[round(x.last_setpoint_t_s, 2), round(x.failsafe_t_s, 2)]
                                        for v in sim.vehicles for x in v.offboard_losses],
                    "measured_sim_s": [round(sim0, 1), round(sim.sim_time_s, 1)], "slipped_s": round(sim.slipped_s, 2)}

    print(json.dumps(asyncio.run(main())), flush=True)


_CONNECT_TIMEOUT_S = 30.0


async def companion(url: str, stop: asyncio.Event, tick_wall_s: float) -> int:
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.action import ActionAsync
    from mavsdk.asyncio.plugins.offboard import OffboardAsync, VelocityBodyYawspeed
    from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as sdk:
        await sdk.add_any_connection(url)
        # None when no heartbeat came in time (the stub's process starts slowly on a busy machine):
        # the plugins cannot be built on it, so say so instead of failing inside them.
        system = await sdk.first_autopilot(timeout_s=_CONNECT_TIMEOUT_S)
        if system is None:
            raise RuntimeError(f"no autopilot heartbeat on {url} within {_CONNECT_TIMEOUT_S:g} s")
        tel, act, off = TelemetryAsync(system), ActionAsync(system), OffboardAsync(system)
        async with contextlib.aclosing(tel.subscribe_health_all_ok()) as health:
            async for ok in health:
                if ok:
                    break
        await act.arm()
        await act.takeoff()
        async with contextlib.aclosing(tel.subscribe_in_air()) as air:
            async for flying in air:
                if flying:
                    break
        samples = 0

        async def setpoints() -> None:
            # One setpoint per planner tick (0.5 s of sim time), as the companion does; the
            # planner's own cost is not part of this benchmark.
            while not stop.is_set():
                await off.set_velocity_body(VelocityBodyYawspeed(10.0, 0.0, 0.0, 5.0))
                await asyncio.sleep(tick_wall_s)

        async def telemetry() -> None:
            nonlocal samples
            async with contextlib.aclosing(tel.subscribe_position_velocity_ned()) as positions:
                async for _ in positions:
                    samples += 1

        async with asyncio.TaskGroup() as tg:
            tasks = [tg.create_task(setpoints()), tg.create_task(telemetry())]
            await asyncio.sleep(tick_wall_s)  # the stream runs before OFFBOARD is asked for (PX4 rule)
            await off.start()
            await stop.wait()
            for t in tasks:
                t.cancel()
        return samples


def free_ports(n: int) -> list[int]:
    socks = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(n)]
    for s in socks:
        s.bind(("0.0.0.0", 0))
    ports = [s.getsockname()[1] for s in socks]
    for s in socks:
        s.close()
    return ports


async def one_run(args: argparse.Namespace) -> dict:
    api0, api1, gcs = free_ports(3)
    ports = json.dumps({"api": [api0, api1], "gcs": gcs})
    sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sink.bind(("127.0.0.1", gcs))
    sink.setblocking(False)
    loop = asyncio.get_running_loop()
    drained = 0

    def drain() -> None:
        nonlocal drained
        with contextlib.suppress(BlockingIOError):
            while True:
                sink.recv(4096)
                drained += 1

    loop.add_reader(sink.fileno(), drain)
    proc = await asyncio.create_subprocess_exec(
        sys.executable, __file__, "--child", "--ports", ports, "--seconds", str(args.seconds),
        "--speedup", str(args.speedup), "--warmup", str(args.warmup), stdout=asyncio.subprocess.PIPE)
    stop = asyncio.Event()
    tick = 0.5 / args.speedup
    try:
        clients = [asyncio.create_task(companion(f"udpin://0.0.0.0:{p}", stop, tick)) for p in (api0, api1)]
        out, _ = await proc.communicate()
        stop.set()
        samples = await asyncio.gather(*clients)
    finally:
        loop.remove_reader(sink.fileno())
        sink.close()
        if proc.returncode is None:
            proc.kill()
    result = json.loads(out.decode().strip().splitlines()[-1])
    result["client_position_samples"] = samples
    result["gcs_datagrams"] = drained
    return result


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=3)
    p.add_argument("--seconds", type=float, default=10.0, help="measured wall seconds per run")
    p.add_argument("--warmup", type=float, default=4.0, help="wall seconds before measuring (takeoff)")
    p.add_argument("--speedup", type=float, default=20.0)
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--ports", default="", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.child:
        child(args)
        return
    print(machine_line(), flush=True)
    results = []
    for i in range(args.runs):
        try:
            r = asyncio.run(one_run(args))
        except RuntimeError as exc:
            sys.exit(f"bench_sim_bridge: {exc}")
        results.append(r)
        print(f"run {i + 1}: cpu {r['cpu_fraction']:.3f} core total ({r['cpu_fraction'] / 2:.3f}/vehicle), "
              f"speed {r['speedup']:.2f}x, tx {r['tx_msg_s']:.0f} msg/s, rx {r['rx_msg_s']:.0f} msg/s, "
              f"modes {r['modes']}, offboard losses {r['offboard_losses']} in sim {r['measured_sim_s']}, "
              f"slipped {r['slipped_s']} s", flush=True)
    med = statistics.median
    cpu = med(r["cpu_fraction"] for r in results)
    print(f"\nsim_bridge, 2 vehicles at {args.speedup:g}x, full telemetry + MAVSDK offboard clients "
          f"({args.runs} runs x {args.seconds:g} s):")
    print(f"  CPU per vehicle (median): {cpu / 2:.3f} core   (total {cpu:.3f}; target < 0.5 per vehicle)")
    print(f"  achieved speed factor (median): {med(r['speedup'] for r in results):.2f}x of {args.speedup:g}x")
    print(f"  messages sent (median): {med(r['tx_msg_s'] for r in results):.0f}/s; "
          f"client position samples per run: {[r['client_position_samples'] for r in results]}")


if __name__ == "__main__":
    main()
