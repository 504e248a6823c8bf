"""The Vehicle port in process: the SITL stub's sans-I/O vehicles driven directly. No sockets, no MAVSDK.

    async with open_inprocess_fleet(mission) as fleet:
        a = fleet.vehicle("a")            # an InProcessVehicle: the whole Vehicle port
        await a.wait_ready(5.0)
        await a.arm()

One :class:`InProcessFleet` owns a :class:`~sim_bridge.vehicle.SimVehicle` per mission vehicle
and one sim clock. Its driver task advances every vehicle together by one physics step per event
loop turn (``speedup=None``: as fast as the loop turns) or paced at a speed factor by the stub's
own :class:`~sim_bridge.clock.SimClock`; the moving obstacles' ADSB_VEHICLE reports come from the
same clock, as in the stub. The companion's tasks get a turn after every step, so a setpoint
computed from a sample reaches the vehicle before the next step: the flight does not depend on
the machine's load and is repeatable.

pymavlink is only the codec. Everything the companion sends is a real ``MAVLink_*_message`` built
and packed by the companion's own ``MAVLink`` encoder (as MAVSDK's identity:
``sim_bridge.vehicle.px4.COMPANION_SYSTEM_ID``, component 190); ``SimVehicle.handle`` answers it at once and its replies (COMMAND_ACK, mission
protocol, PARAM_VALUE, the heartbeat after a mode change) are read from the messages it emits,
exactly as the streamed telemetry is. ``wire=True`` also packs and parses every message in both
directions, as the UDP path does. Frames convert only through :mod:`uav_model.frames`.

What differs from the socket path (see docs/companion.md): no MAVSDK in between, so there is no
20 Hz setpoint resend of MAVSDK's offboard plugin (setpoints reach the vehicle only when the
companion sends them); commands are answered in the same turn; streams are paced in sim time only
(no wall-clock caps); no link faults, no GCS link, no .tlog.

    fleet.py      InProcessOptions, InProcessFleet (the sim clock and its driver), open_inprocess_fleet
    vehicle.py    InProcessVehicle: the port's commands, mission protocol and parameters
    telemetry.py  the vehicle's messages folded into the port's board (status, pose, traffic)
    link.py       the companion's identity on the link, the codec, the PX4 mode and result tables
"""

from companion.sitl.inprocess.fleet import InProcessFleet, InProcessOptions, open_inprocess_fleet
from companion.sitl.inprocess.vehicle import InProcessVehicle

__all__ = ["InProcessFleet", "InProcessOptions", "InProcessVehicle", "open_inprocess_fleet"]
