"""MAVProxy, headless, on the stub's GCS link: sees both vehicles, arms one and changes modes.

MAVProxy runs as a child process (``python -m MAVProxy.mavproxy --master=udpin:...``) driven
over its stdin, exactly as a user types. Its ``mode NAME`` command is broken for PX4 in
MAVProxy 1.8.75 (it passes pymavlink's ``px4_map`` tuple where a number is expected and fails
with "required argument is not a float"), so modes are changed with MAVProxy's generic
``long DO_SET_MODE <base> <main> <sub>``, which is what ``mode`` would send.
"""

from __future__ import annotations

import asyncio
import contextlib
import importlib.util
import re
import sys

import pytest
from pymavlink.dialects.v20 import common as mavlink


from uav_model.frames import local_to_geodetic
from uav_model.mission import parse_mission
from sim_bridge.bridge import SimOptions
from sim_bridge.vehicle.px4 import FlightMode, Px4AutoSubMode, Px4MainMode
from sim_bridge.testing import stub_on_free_ports

MISSION_YAML = """
name: mavproxy
area: {x_min_m: 0, y_min_m: 0, x_max_m: 1000, y_max_m: 1000}
stations: {A: [100, 100], B: [900, 900]}
vehicles:
  - {name: a, start: A, goal: B, cruise_alt_m: 5}
  - {name: b, start: B, goal: A, cruise_alt_m: 5}
"""
CUSTOM = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED

# MAVProxy is not in the `test` extra: its GUI stack (vtk, opencv) is ~900 MB that a headless GCS
# never loads. .ci/run installs it without those.
pytestmark = pytest.mark.skipif(
    importlib.util.find_spec("MAVProxy") is None,
    reason="needs MAVProxy (the gcs extra, headless): pip install --no-deps 'MAVProxy>=1.8.70' pyserial pynmeagps defusedxml")


class MavProxy:
    def __init__(self, proc: asyncio.subprocess.Process):
        self.proc = proc
        self.lines: list[str] = []
        self._new = asyncio.Event()

    async def pump(self) -> None:
        assert self.proc.stdout is not None
        while line := await self.proc.stdout.readline():
            self.lines.append(line.decode(errors="replace").rstrip())
            self._new.set()

    async def send(self, command: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(command.encode() + b"\n")
        await self.proc.stdin.drain()

    async def expect(self, pattern: str, timeout_s: float = 15.0, after: int = 0) -> re.Match[str]:
        """The first output line (from index ``after``) matching ``pattern``."""
        rx = re.compile(pattern)
        async with asyncio.timeout(timeout_s):
            seen = after
            while True:
                for line in self.lines[seen:]:
                    if m := rx.search(line):
                        return m
                seen = len(self.lines)
                self._new.clear()
                await self._new.wait()


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_mavproxy_sees_both_vehicles_and_arms_and_changes_modes():
    mission = parse_mission(MISSION_YAML, "mavproxy.yaml")

    async def scenario():
        async with stub_on_free_ports(mission, SimOptions(speedup=2.0)) as sim:
            proc = await asyncio.create_subprocess_exec(
                sys.executable, "-m", "MAVProxy.mavproxy", f"--master=udpin:127.0.0.1:{sim.options.gcs_port}",
                "--no-state", "--default-modules=arm,cmdlong,mode", "--source-system=250",
                stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT)
            mp = MavProxy(proc)
            pump = asyncio.create_task(mp.pump())
            try:
                await mp.expect(r"Detected vehicle 1:1", 30.0)
                await mp.expect(r"Detected vehicle 2:1")

                # Heartbeats and positions of both vehicles, each where its station is. MAVProxy
                # shows the messages of the vehicle it has selected.
                hold = FlightMode.HOLD.custom_mode
                for spec in mission.vehicles:
                    await mp.send(f"vehicle {spec.system_id}")
                    await mp.expect(rf"Set vehicle {spec.system_id}")
                    lat, lon, _ = local_to_geodetic(mission.origin, *spec.start_enu_m)
                    await mp.send("watch GLOBAL_POSITION_INT")
                    await mp.expect(rf"GLOBAL_POSITION_INT {{.*lat : {round(lat * 1e7)}, lon : {round(lon * 1e7)},",
                                    after=len(mp.lines))
                    await mp.send("watch HEARTBEAT")
                    await mp.expect(rf"HEARTBEAT {{type : 2, autopilot : 12, .*custom_mode : {hold},", after=len(mp.lines))
                    await mp.send("watch")

                # Commands reach the selected vehicle only.
                await mp.send("vehicle 2")
                await mp.expect(r"Set vehicle 2")
                await mp.send("arm throttle")
                await mp.expect(r"COMMAND_ACK: COMPONENT_ARM_DISARM: ACCEPTED")
                assert sim.vehicle("b").armed and not sim.vehicle("a").armed
                await mp.send(f"long DO_SET_MODE {CUSTOM} {Px4MainMode.AUTO} {Px4AutoSubMode.TAKEOFF}")
                await mp.expect(r"COMMAND_ACK: DO_SET_MODE: ACCEPTED")
                assert await sim.wait_for(lambda: sim.vehicle("b").in_air, 10.0)
                assert sim.vehicle("b").mode is FlightMode.TAKEOFF and sim.vehicle("a").mode is FlightMode.HOLD
                # MAVProxy shows the new mode of the vehicle it watches.
                await mp.send("watch HEARTBEAT")
                await mp.expect(rf"custom_mode : {FlightMode.TAKEOFF.custom_mode}|custom_mode : {hold}, system_status : 4",
                                after=len(mp.lines))
                await mp.send("watch")

                # Armed, no setpoints: PX4 ACKs ACCEPTED, then refuses the switch and says so.
                await mp.send(f"long DO_SET_MODE {CUSTOM} {Px4MainMode.OFFBOARD} 0")
                await mp.expect(r"COMMAND_ACK: DO_SET_MODE: ACCEPTED", after=len(mp.lines) - 1)
                await mp.expect(r"Switching to Offboard is currently not available")
                assert sim.vehicle("b").mode is not FlightMode.OFFBOARD

                await mp.send("vehicle 1")
                await mp.expect(r"Set vehicle 1")
                # Disarmed, PX4 selects OFFBOARD without setpoints (its requirement then gates arming).
                await mp.send(f"long DO_SET_MODE {CUSTOM} {Px4MainMode.OFFBOARD} 0")
                await mp.expect(r"COMMAND_ACK: DO_SET_MODE: ACCEPTED", after=len(mp.lines) - 1)
                assert await sim.wait_for(lambda: sim.vehicle("a").mode is FlightMode.OFFBOARD, 5.0)
                await mp.send("arm throttle")
                await mp.expect(r"Arming denied: no offboard signal")
                assert not sim.vehicle("a").armed
                await mp.send(f"long DO_SET_MODE {CUSTOM} {Px4MainMode.AUTO} {Px4AutoSubMode.LAND}")
                await mp.expect(r"COMMAND_ACK: DO_SET_MODE: ACCEPTED", after=len(mp.lines) - 1)
                assert await sim.wait_for(lambda: sim.vehicle("a").mode is FlightMode.LAND, 5.0)
                assert sim.vehicle("b").mode is not FlightMode.LAND
            finally:
                if proc.returncode is None:
                    proc.terminate()
                    try:
                        async with asyncio.timeout(5):
                            await proc.wait()
                    except TimeoutError:
                        proc.kill()
                        await proc.wait()
                pump.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await pump

    asyncio.run(scenario())
