"""Every vehicle of a mission on one sim clock, and the driver task that advances them together."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from dataclasses import dataclass, field

from uav_model.mission import Mission, VehicleSpec
from companion.sitl.inprocess.link import INPROCESS_PROFILE, LINK
from companion.sitl.inprocess.vehicle import InProcessVehicle
from companion.vehicle.port import Vehicle
from sim_bridge.clock import SimClock
from sim_bridge.vehicle.energy import EnergyModel
from sim_bridge.vehicle import SimVehicle


@dataclass(frozen=True)
class InProcessOptions:
    """How the in-process sim runs. ``speedup`` None: one physics step per event-loop turn."""

    speedup: float | None = None
    physics_dt_s: float = 0.02
    speed_headroom: float = 1.0  # vehicle speed limit = mission speed * headroom, as SimOptions
    energy: EnergyModel = field(default_factory=EnergyModel)
    wire: bool = False  # pack and parse every message both ways (slower; exercises the byte codec)
    params: tuple[tuple[str, float], ...] = ()  # autopilot parameters at boot (NAME, VALUE)

    def __post_init__(self) -> None:
        SimClock(1.0 if self.speedup is None else self.speedup, self.physics_dt_s, 0.0)  # ClockError if unusable



class InProcessFleet:
    """Every vehicle of a mission on one sim clock, driven from asyncio. Use :func:`open_inprocess_fleet`.

    Without the driver (a bare ``InProcessFleet``), ``await fleet.step()`` advances it by hand: the
    vehicles then send nothing until stepped.
    """

    def __init__(self, mission: Mission, options: InProcessOptions | None = None):
        self.mission = mission
        self.options = options or InProcessOptions()
        o = self.options
        self._vehicles: dict[str, InProcessVehicle] = {}
        for spec in mission.vehicles:
            sim = SimVehicle(spec, mission, speed_headroom=o.speed_headroom, energy=o.energy,
                             speed_factor=1.0 if o.speedup is None else o.speedup, params=dict(o.params))
            sim.add_link(LINK, INPROCESS_PROFILE)
            self._vehicles[spec.name] = InProcessVehicle(self, sim, mission.origin, o.wire)
        self._steps = 0

    @property
    def sim_time_s(self) -> float:
        return self._steps * self.options.physics_dt_s

    @property
    def steps(self) -> int:
        return self._steps

    def vehicle(self, name: str) -> InProcessVehicle:
        try:
            return self._vehicles[name]
        except KeyError:
            raise KeyError(f"the mission has no vehicle {name!r} (vehicles: {', '.join(self._vehicles)})") from None

    @property
    def vehicles(self) -> tuple[InProcessVehicle, ...]:
        return tuple(self._vehicles.values())

    def connections(self) -> dict[str, str]:
        """A label per vehicle where the socket path has a URL (for reports and summary.json)."""
        return {name: f"inprocess://{v.system_id}" for name, v in self._vehicles.items()}

    @asynccontextmanager
    async def open_vehicle(self, spec: VehicleSpec, url: str = "") -> AsyncIterator[Vehicle]:
        """The runner's per-vehicle opener: the vehicle is already there while the fleet runs."""
        yield self.vehicle(spec.name)

    async def step(self) -> None:
        """Advance every vehicle by one physics step, then hand each its messages of this step."""
        dt = self.options.physics_dt_s
        stepped = [(v, v.sim.step(dt)) for v in self._vehicles.values()]
        self._steps += 1
        t = self.sim_time_s
        for v, emits in stepped:
            # Wall-clock duties run on sim time: in process there is no other clock to honour.
            emits += v.sim.poll(t)
            emits += v.sim.telemetry(t)
            await v.deliver(emits)

    async def run(self) -> None:
        """The driver: step forever, giving the companion's tasks a turn after every step."""
        speedup = self.options.speedup
        if speedup is None:
            while True:
                await self.step()
                await asyncio.sleep(0)
        loop = asyncio.get_running_loop()
        clock = SimClock(speedup, self.options.physics_dt_s, loop.time())
        while True:
            due = clock.steps_due(loop.time())
            for _ in range(due):
                clock.advance()
                await self.step()
                await asyncio.sleep(0)
            if not due:
                await asyncio.sleep(max(0.0, clock.wall_of_next_step() - loop.time()))


@asynccontextmanager
async def open_inprocess_fleet(mission: Mission, options: InProcessOptions | None = None
                               ) -> AsyncIterator[InProcessFleet]:
    """Build the mission's vehicles and run their sim clock while the context is open."""
    fleet = InProcessFleet(mission, options)
    try:
        async with asyncio.TaskGroup() as tg:
            driver = tg.create_task(fleet.run(), name="inprocess-sim")
            try:
                # The autopilot was powered up before the companion connects: PX4 refuses to arm
                # for its first seconds (heading estimate settling).
                while not all(v.sim.modes.healthy() for v in fleet.vehicles):
                    await asyncio.sleep(0 if fleet.options.speedup is None else fleet.options.physics_dt_s)
                yield fleet
            finally:
                driver.cancel()
    except BaseExceptionGroup as group:
        # The driver only ends by cancellation: hand the caller's own error back unwrapped.
        if len(group.exceptions) == 1:
            raise group.exceptions[0] from None
        raise
