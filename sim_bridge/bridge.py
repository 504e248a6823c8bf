"""The thin asyncio UDP layer around the sans-I/O vehicles, and the embedding API.

    async with SimBridge(mission, SimOptions(speedup=10)) as sim:
        ...                       # vehicles are live on UDP; sim.vehicle("a").mode, sim.sim_time_s

Sockets (all bound to loopback unless told otherwise):
- one API socket per vehicle, sending first to ``host:api_port_base + i`` (PX4 SITL convention;
  the companion listens with ``udpin://0.0.0.0:14540+i``) and answering whoever writes to it;
- one GCS socket carrying every vehicle, sending to ``host:gcs_port`` and to every peer that
  writes to it (QGroundControl, MAVProxy).

Each socket decodes with its own pymavlink parser per peer (``MAVLink.parse_buffer``) and each
(vehicle, link) encodes with its own ``MAVLink`` object, so sequence numbers are per link as in
PX4. Nothing here blocks: datagrams go out through ``transport.sendto`` and come in through
``DatagramProtocol.datagram_received``.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections import Counter
from pathlib import Path
from typing import Any, Callable, Hashable

from pymavlink.dialects.v20 import common as mavlink

from uav_model.mission import Mission
from sim_bridge.admission import Admission
from sim_bridge.clock import SimClock
from sim_bridge.endpoint import Endpoint, Link
from sim_bridge.faults import Blackout, FaultConfig, LinkFaults
from sim_bridge.options import SimBridgeError, SimOptions
from sim_bridge.vehicle.px4 import FlightMode
from sim_bridge.statustext import StatustextSplitter
from sim_bridge.tlog import TlogSet
from sim_bridge.vehicle import Emit, SimVehicle

__all__ = ["API_LINK", "GCS_LINK", "SimBridge", "SimBridgeError", "SimOptions", "run_stub"]

log = logging.getLogger(__name__)

API_LINK = "api"
GCS_LINK = "gcs"


class SimBridge:
    """The running stub: vehicles, sockets, sim clock. Use as ``async with``."""

    def __init__(self, mission: Mission, options: SimOptions | None = None):
        self.mission = mission
        self.options = options or SimOptions()
        o = self.options
        if o.api_ports is not None and len(o.api_ports) < len(mission.vehicles):
            raise SimBridgeError(f"api_ports has {len(o.api_ports)} port(s) for {len(mission.vehicles)} vehicles")
        SimClock(o.speedup, o.physics_dt_s, 0.0)  # fail early on a bad speed factor or step
        try:
            self.vehicles: tuple[SimVehicle, ...] = tuple(
                SimVehicle(spec, mission, speed_headroom=o.speed_headroom, energy=o.energy, speed_factor=o.speedup,
                           params=dict(o.params)) for spec in mission.vehicles)
        except ValueError as exc:
            raise SimBridgeError(str(exc)) from None
        self._by_sysid = {v.system_id: i for i, v in enumerate(self.vehicles)}
        self.admission = Admission(o.allow_sysids, o.signing_key)
        self._texts = [StatustextSplitter(v.mav) for v in self.vehicles]  # PX4's STATUSTEXT wire form
        self._links: list[dict[str, Link]] = []
        for v in self.vehicles:
            links = {API_LINK: self._make_link(v, API_LINK, with_faults=not o.faults.is_clean)}
            v.add_link(API_LINK, o.api_profile)
            if o.gcs_port is not None:
                links[GCS_LINK] = self._make_link(v, GCS_LINK, with_faults=o.faults_on_gcs and not o.faults.is_clean)
                v.add_link(GCS_LINK, o.gcs_profile)
            self._links.append(links)
        self.stats: Counter[str] = Counter()
        self._clock: SimClock | None = None
        self._api: list[Endpoint] = []
        self._gcs: Endpoint | None = None
        self._task: asyncio.Task | None = None
        self._tlog: TlogSet | None = None
        self._timers: set[asyncio.TimerHandle] = set()
        self._cpu_start = 0.0
        self._wall_start = 0.0
        self._running = False

    def _make_link(self, v: SimVehicle, name: str, with_faults: bool) -> Link:
        o = self.options
        fo = LinkFaults(o.faults, o.seed, f"{v.name}/{name}/out") if with_faults else None
        fi = LinkFaults(o.faults, o.seed, f"{v.name}/{name}/in") if with_faults else None
        return Link(name, self.admission.sign(mavlink.MAVLink(None, v.system_id, v.component_id),
                                              link_id=0 if name == API_LINK else 1), fo, fi)

    # ================================================================== lifecycle =========
    async def __aenter__(self) -> "SimBridge":
        await self.start()
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.stop()

    async def start(self) -> None:
        """Bind the sockets and start the sim loop. Raises SimBridgeError if a socket cannot bind."""
        if self._running:
            return
        loop = asyncio.get_running_loop()
        o = self.options
        bind = o.resolved_bind_host
        try:
            for i, v in enumerate(self.vehicles):
                _, ep = await loop.create_datagram_endpoint(lambda i=i: Endpoint(self, API_LINK, i), local_addr=(bind, 0))
                ep.default_remote = (o.host, o.api_port(i))
                self._api.append(ep)
            if o.gcs_port is not None:
                _, ep = await loop.create_datagram_endpoint(lambda: Endpoint(self, GCS_LINK, None), local_addr=(bind, 0))
                ep.default_remote = (o.host, o.gcs_port)
                self._gcs = ep
        except OSError as exc:
            self._close_sockets()
            raise SimBridgeError(f"cannot open UDP sockets on {bind}: {exc}") from None
        self._clock = SimClock(o.speedup, o.physics_dt_s, loop.time(),
                               max_lag_steps=max(1, math.ceil(o.max_catchup_sim_s / o.physics_dt_s)))
        if o.tlog_dir is not None:
            epoch_at_start = time.time()  # tlog stamps: this wall instant plus the sim seconds since
            self._tlog = TlogSet(Path(o.tlog_dir), self.mission.name,
                                 [(v.system_id, v.name) for v in self.vehicles],
                                 lambda: epoch_at_start + self.sim_time_s, per_vehicle=o.tlog_per_vehicle)
        self._cpu_start = time.process_time()
        self._wall_start = loop.time()
        self._running = True
        self._task = asyncio.create_task(self._run(), name="sim_bridge-loop")
        log.info("sim_bridge: %d vehicle(s) at %gx; GCS %s", len(self.vehicles), o.speedup,
                 "off" if o.gcs_port is None else f"{o.host}:{o.gcs_port}")

    async def stop(self) -> None:
        """Stop the loop, close sockets, finish the tlog. Safe to call twice."""
        if not self._running:
            return
        self._running = False
        task, self._task = self._task, None
        if task is not None:
            task.cancel()
            try:
                await task
            except asyncio.CancelledError:
                pass
        for handle in self._timers:
            handle.cancel()
        self._timers.clear()
        self._close_sockets()
        if self._tlog is not None:
            self._tlog.close()
        log.info("sim_bridge stopped at sim t=%.1f s; %s", self.sim_time_s, dict(self.stats))

    def _close_sockets(self) -> None:
        for ep in self._api + ([self._gcs] if self._gcs else []):
            if ep.transport is not None:
                ep.transport.close()
        self._api = []
        self._gcs = None

    async def _run(self) -> None:
        loop = asyncio.get_running_loop()
        clock = self._clock
        assert clock is not None
        dt = clock.dt_s
        o = self.options
        while True:
            now = loop.time()
            try:
                for _ in range(clock.steps_due(now)):
                    clock.advance()
                    for i, v in enumerate(self.vehicles):
                        self._dispatch(i, v.step(dt))
                for i, v in enumerate(self.vehicles):
                    self._dispatch(i, v.poll(now))
                    self._dispatch(i, v.telemetry(now))
                if self._tlog is not None:
                    self._tlog.maybe_flush(now)
            except Exception:  # noqa: BLE001 - the loop must outlive any one bad tick
                self.stats["loop_errors"] += 1
                log.exception("sim_bridge: error in the sim loop")
            delay = max(clock.wall_of_next_step() - loop.time(), o.min_tick_wall_s)
            await asyncio.sleep(delay)

    # ================================================================== I/O ===============
    def _on_datagram(self, ep: Endpoint, data: bytes, addr: tuple[str, int]) -> None:
        self.stats["rx_datagrams"] += 1
        try:
            if ep.vehicle_index is not None:
                link = self._links[ep.vehicle_index][API_LINK]
                delay = link.faults_in.verdict(self.sim_time_s) if link.faults_in else 0.0
                if delay is None:
                    return
                if delay > 0:
                    self._later(delay, self._decode, ep, data, addr)
                    return
            self._decode(ep, data, addr)
        except Exception:  # noqa: BLE001 - garbage must never reach the loop
            self.stats["rx_errors"] += 1
            log.debug("sim_bridge: error on datagram from %s", addr, exc_info=True)

    def _decode(self, ep: Endpoint, data: bytes, addr: tuple[str, int]) -> None:
        if not self._running:
            return
        parser = ep.parser_for(addr)
        try:
            msgs = parser.parse_buffer(data) or []
        except Exception:  # noqa: BLE001 - pymavlink raises on some malformed frames
            self.stats["garbage"] += 1
            log.debug("sim_bridge: undecodable datagram from %s on %s", addr, ep.socket_name, exc_info=True)
            parser.buf = bytearray()  # resynchronise on the next datagram
            parser.buf_index = 0
            return
        for msg in msgs:
            if not self.admission.admits(msg, data, ep.socket_name, addr):  # counted and logged there
                continue
            if msg.get_type() == "BAD_DATA":
                self.stats["garbage"] += 1
                log.debug("sim_bridge: garbage from %s on %s: %s", addr, ep.socket_name, getattr(msg, "reason", ""))
                continue
            self.stats["rx_messages"] += 1
            if self._tlog is not None and ep.socket_name == GCS_LINK:
                self._tlog.write(msg.get_msgbuf(), getattr(msg, "target_system", 0) or None)
            if ep.vehicle_index is not None:
                self._deliver(ep.vehicle_index, msg, API_LINK, addr)
                continue
            target = getattr(msg, "target_system", 0)
            if target == 0:
                for i in range(len(self.vehicles)):
                    self._deliver(i, msg, GCS_LINK, addr)
            elif target in self._by_sysid:
                self._deliver(self._by_sysid[target], msg, GCS_LINK, addr)
            else:
                self.stats["wrong_target"] += 1

    def _deliver(self, index: int, msg: Any, link: str, peer: Hashable) -> None:
        self._dispatch(index, self.vehicles[index].handle(msg, link, peer))

    def _dispatch(self, index: int, emits: list[Emit]) -> None:
        links = self._links[index]
        for e in self._texts[index].expand(emits):
            names = links if e.link is None else (e.link,)
            for name in names:
                link = links.get(name)
                if link is not None:
                    self._send(index, link, e.msg, e.peer)

    def _send(self, index: int, link: Link, msg: Any, peer: Hashable | None) -> None:
        ep = self._api[index] if link.name == API_LINK else self._gcs
        if ep is None or ep.transport is None:
            return
        try:
            buf = msg.pack(self.admission.stamp(link.encoder))
        except Exception:  # noqa: BLE001 - a message that cannot be packed is a bug, not a crash
            self.stats["pack_errors"] += 1
            log.exception("sim_bridge: cannot pack %s", msg.get_type())
            return
        link.encoder.seq = (link.encoder.seq + 1) % 256
        if self._tlog is not None and link.name == GCS_LINK:
            self._tlog.write(buf, self.vehicles[index].system_id)
        for dest in ([peer] if peer is not None else ep.destinations()):
            delay = link.faults_out.verdict(self.sim_time_s) if link.faults_out else 0.0
            if delay is None:
                continue
            if delay > 0:
                self._later(delay, self._sendto, ep, buf, dest)
            else:
                self._sendto(ep, buf, dest)

    def _sendto(self, ep: Endpoint, buf: bytes, dest: Hashable) -> None:
        if ep.transport is None or ep.transport.is_closing():
            return
        try:
            ep.transport.sendto(buf, dest)
            self.stats["tx_messages"] += 1
        except OSError:
            self.stats["socket_errors"] += 1

    def _later(self, delay_s: float, fn: Callable[..., None], *args: Any) -> None:
        loop = asyncio.get_running_loop()
        handle: asyncio.TimerHandle

        def run() -> None:
            self._timers.discard(handle)
            fn(*args)

        handle = loop.call_later(delay_s, run)
        self._timers.add(handle)

    # ================================================================== accessors =========
    @property
    def sim_time_s(self) -> float:
        return self._clock.sim_time_s if self._clock is not None else 0.0

    @property
    def achieved_speedup(self) -> float:
        if self._clock is None:
            return 0.0
        return self._clock.achieved_speedup(asyncio.get_running_loop().time())

    @property
    def slipped_s(self) -> float:
        """Sim seconds given up because the stub fell behind the wall clock (see max_catchup_sim_s)."""
        return self._clock.slipped_s if self._clock is not None else 0.0

    @property
    def cpu_fraction(self) -> float:
        """Process CPU time over wall time since start (all vehicles together)."""
        if not self._running:
            return 0.0
        wall = asyncio.get_running_loop().time() - self._wall_start
        return (time.process_time() - self._cpu_start) / wall if wall > 0 else 0.0

    def vehicle(self, key: str | int) -> SimVehicle:
        """A vehicle by mission name or by index."""
        if isinstance(key, int):
            return self.vehicles[key]
        for v in self.vehicles:
            if v.name == key:
                return v
        raise KeyError(key)

    @property
    def collision_count(self) -> int:
        return sum(v.collision_count for v in self.vehicles)

    def modes(self) -> dict[str, FlightMode]:
        return {v.name: v.mode for v in self.vehicles}

    def api_address(self, index: int) -> tuple[str, int]:
        """The local (host, port) of vehicle ``index``'s API socket."""
        ep = self._api[index]
        assert ep.transport is not None
        return ep.transport.get_extra_info("sockname")[:2]

    @property
    def gcs_address(self) -> tuple[str, int] | None:
        if self._gcs is None or self._gcs.transport is None:
            return None
        return self._gcs.transport.get_extra_info("sockname")[:2]

    @property
    def tlog_path(self) -> Path | None:
        """The combined GCS-stream log (None without --tlog)."""
        return None if self._tlog is None else self._tlog.combined.path

    @property
    def tlog_paths(self) -> list[Path]:
        """The combined log, then one per vehicle if asked."""
        return [] if self._tlog is None else self._tlog.paths

    def blackout(self, duration_s: float, vehicle: str | int | None = None) -> None:
        """Cut the API link(s) for ``duration_s`` sim seconds from now (both directions)."""
        targets = range(len(self.vehicles)) if vehicle is None else [self.vehicles.index(self.vehicle(vehicle))]
        b = Blackout(self.sim_time_s, duration_s)
        for i in targets:
            link = self._links[i][API_LINK]
            if link.faults_out is None:
                link.faults_out = LinkFaults(FaultConfig(), self.options.seed, f"{self.vehicles[i].name}/api/out")
                link.faults_in = LinkFaults(FaultConfig(), self.options.seed, f"{self.vehicles[i].name}/api/in")
            link.faults_out.add_blackout(b)
            assert link.faults_in is not None
            link.faults_in.add_blackout(b)

    def fault_counts(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for v, links in zip(self.vehicles, self._links):
            for link in links.values():
                for direction, f in (("out", link.faults_out), ("in", link.faults_in)):
                    if f is not None:
                        out[f"{v.name}/{link.name}/{direction}/dropped"] = f.dropped
                        out[f"{v.name}/{link.name}/{direction}/passed"] = f.passed
        return out

    async def wait_for(self, predicate: Callable[[], bool], timeout_s: float, poll_s: float = 0.01) -> bool:
        """Wait (wall clock) until ``predicate()`` holds; False on timeout."""
        try:
            async with asyncio.timeout(timeout_s):
                while not predicate():
                    await asyncio.sleep(poll_s)
        except TimeoutError:
            return False
        return True


async def run_stub(mission: Mission, options: SimOptions | None = None, *, stop: asyncio.Event | None = None,
                   on_ready: Callable[[SimBridge], None] | None = None) -> SimBridge:
    """Run the stub until ``stop`` is set (or the task is cancelled); returns the stopped bridge."""
    sim = SimBridge(mission, options)
    async with sim:
        # Ready = booted: PX4 refuses to arm until its estimator settles (a few sim seconds).
        await sim.wait_for(lambda: all(v.modes.healthy() for v in sim.vehicles), timeout_s=3600.0)
        if on_ready is not None:
            on_ready(sim)
        if stop is None:
            await asyncio.Event().wait()
        else:
            await stop.wait()
    return sim
