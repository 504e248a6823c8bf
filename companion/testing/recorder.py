"""A GCS-side telemetry recorder: listens like QGroundControl on a UDP port and records every
vehicle it hears, so scenario tests assert on what the vehicles *report*, not on what the
companion believes about itself.

It is asyncio and never blocks: datagrams arrive through a ``DatagramProtocol``, are decoded by
one pymavlink parser per sender, and are appended to per-vehicle logs. Waiting is event-driven
(:meth:`TelemetryRecorder.wait_until`) with a timeout on every wait.

Every record is one tuple appended to a list, so another thread may copy a log while it grows
(the pytest plugin reads it from the test's thread). Events without a MAVLink time stamp (mode
changes, STATUSTEXT, ADS-B) are stamped with the wall clock on arrival and placed on the
vehicle's sim clock by interpolating between the stamped messages around them: a vehicle sends
its mode-change HEARTBEAT at once, so this is exact to the link's jitter.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from uav_model.frames import ned_to_enu
from companion.planning.metrics import Track
from sim_bridge.vehicle.px4 import GCS_COMPONENT_ID, GCS_SYSTEM_ID, mode_name

_STAMPED = {"LOCAL_POSITION_NED", "GLOBAL_POSITION_INT", "ATTITUDE"}  # carry time_boot_ms


@dataclass(frozen=True)
class AdsbReport:
    """One ADSB_VEHICLE as heard on the link (``wall_s``: arrival, time.monotonic())."""

    wall_s: float
    callsign: str
    lat_deg: float
    lon_deg: float
    course_deg: float  # over ground, clockwise from north
    speed_m_s: float


@dataclass
class VehicleLog:
    """Everything one vehicle said, in arrival order. Sim times are the vehicle's ``time_boot_ms``."""

    system_id: int
    heartbeats: int = 0
    last_mode: str | None = None
    armed: bool = False
    landed_state: int | None = None
    battery_pct: float | None = None
    stamps: list[tuple[float, float]] = field(default_factory=list)  # (wall_s, sim_s) of stamped messages
    positions: list[tuple[float, float, float, float]] = field(default_factory=list)  # (sim_s, x, y, z) ENU m
    api_positions: list[tuple[float, float, float, float]] = field(default_factory=list)  # the same, from a tap
    mode_changes: list[tuple[float, str]] = field(default_factory=list)  # (wall_s, mode); the first is the initial mode
    armed_changes: list[tuple[float, bool]] = field(default_factory=list)  # (wall_s, armed)
    statustexts: list[tuple[float, int, str]] = field(default_factory=list)  # (wall_s, severity, text)
    adsb: list[AdsbReport] = field(default_factory=list)

    # -- time ---------------------------------------------------------------------------------
    @property
    def clock_s(self) -> float | None:
        """The latest sim time the vehicle reported."""
        return self.stamps[-1][1] if self.stamps else None

    def sim_time_at(self, wall_s: float) -> float:
        """The vehicle's sim time at a wall instant, interpolated between stamped messages."""
        return float(self.sim_times_at([wall_s])[0])

    def sim_times_at(self, wall_s) -> np.ndarray:
        """:meth:`sim_time_at` for many instants at once."""
        stamps = list(self.stamps)
        if not stamps:
            return np.zeros(len(wall_s))
        wall, sim = np.asarray(stamps).T
        return np.interp(np.asarray(wall_s, dtype=float), wall, sim)

    # -- modes and arming ---------------------------------------------------------------------
    @property
    def modes(self) -> list[str]:
        """The flight-mode sequence (consecutive repeats folded), the initial mode first."""
        return [m for _, m in list(self.mode_changes)]

    def mode_history(self) -> list[tuple[float, str]]:
        """(sim_s, mode) for each mode change, on the vehicle's clock."""
        changes = list(self.mode_changes)
        return list(zip(self.sim_times_at([w for w, _ in changes]).tolist(), [m for _, m in changes]))

    @property
    def armed_history(self) -> list[bool]:
        return [a for _, a in list(self.armed_changes)]

    @property
    def statustext(self) -> list[str]:
        return [text for _, _, text in list(self.statustexts)]

    # -- position -----------------------------------------------------------------------------
    def track(self, since_mode: str | None = None) -> Track:
        """The ENU ground track from LOCAL_POSITION_NED, strictly increasing in sim time.

        ``since_mode="OFFBOARD"`` starts it at the first OFFBOARD stretch (departure), so flight
        time counts from there, not from power-on and take-off.
        """
        rows = list(self.positions) + list(self.api_positions)
        if not rows:
            raise ValueError(f"no position recorded from system {self.system_id}")
        rows.sort(key=lambda r: r[0])
        t, x, y, _ = np.asarray(rows, dtype=float).T
        if since_mode is not None:
            starts = [s for s, m in self.mode_history() if m == since_mode]
            if not starts:
                raise ValueError(f"system {self.system_id} never reported mode {since_mode} "
                                 f"(modes: {' -> '.join(self.modes)})")
            # Start exactly at the change, interpolated: GCS samples may be seconds of sim time apart.
            t0 = starts[0]
            after = int(np.searchsorted(t, t0, side="right"))
            if after >= len(t):
                raise ValueError(f"system {self.system_id}: no position after entering {since_mode}")
            x0, y0 = float(np.interp(t0, t, x)), float(np.interp(t0, t, y))
            t, x, y = (np.concatenate([[v0], a[after:]]) for v0, a in ((t0, t), (x0, x), (y0, y)))
        keep = np.concatenate([[True], np.diff(t) > 0])  # one sample per instant (both links, duplicates)
        return Track(t[keep], x[keep], y[keep])

    @property
    def position_enu_m(self) -> tuple[float, float] | None:
        """The latest position heard on the GCS link."""
        return (self.positions[-1][1], self.positions[-1][2]) if self.positions else None

    @property
    def altitude_m(self) -> float | None:
        return self.positions[-1][3] if self.positions else None


class _Protocol(asyncio.DatagramProtocol):
    def __init__(self, on_datagram: Callable[[bytes, tuple], None]):
        self.on_datagram = on_datagram

    def datagram_received(self, data: bytes, addr) -> None:
        self.on_datagram(data, addr)


class TelemetryRecorder:
    """Record every vehicle heard on a GCS UDP port.

    >>> async with TelemetryRecorder(port=0) as rec:     # port 0: pick a free one
    ...     await rec.wait_until(lambda r: r.heard(1), timeout_s=5)

    A GCS link is rate-capped in wall time (at 20x the stub sends a position every 2 s of sim
    time there), so the recorder can also :meth:`tap` a vehicle's API link: it says hello to the
    vehicle's API socket, which then streams to it as to any other peer (PX4 does the same), and
    records the positions from there too. Modes and clocks still come from the GCS link only.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 14550):
        self.host = host
        self.port = port
        self.vehicles: dict[int, VehicleLog] = {}
        self.garbage = 0
        self._transport: asyncio.DatagramTransport | None = None
        self._parsers: dict[tuple, mavlink.MAVLink] = {}
        self._addr: dict[int, tuple] = {}  # sysid -> where its GCS datagrams come from
        self._changed = asyncio.Event()
        self._mission_items: dict[int, dict[int, mavlink.MAVLink_mission_item_int_message]] = {}
        self._mission_count: dict[int, int] = {}
        self._tap: asyncio.DatagramTransport | None = None
        self._tap_parsers: dict[tuple, mavlink.MAVLink] = {}
        self._tap_addr: dict[int, tuple] = {}  # sysid -> the vehicle's API socket
        self._acks: list[tuple[int, int, int]] = []  # (sysid, command, result) heard on a tap
        self._encoder = mavlink.MAVLink(None, srcSystem=GCS_SYSTEM_ID, srcComponent=GCS_COMPONENT_ID)
        self._encoder.robust_parsing = True

    async def __aenter__(self) -> "TelemetryRecorder":
        loop = asyncio.get_running_loop()
        self._transport, _ = await loop.create_datagram_endpoint(
            lambda: _Protocol(self._on_datagram), local_addr=(self.host, self.port))
        self.port = self._transport.get_extra_info("sockname")[1]
        return self

    async def __aexit__(self, *exc) -> None:
        for transport in (self._transport, self._tap):
            if transport is not None:
                transport.close()
        self._transport = self._tap = None

    # -- receiving ----------------------------------------------------------------------------

    def _on_datagram(self, data: bytes, addr) -> None:
        parser = self._parsers.get(addr)
        if parser is None:
            parser = mavlink.MAVLink(None)
            parser.robust_parsing = True
            self._parsers[addr] = parser
        try:
            messages = parser.parse_buffer(data) or []
        except Exception:  # noqa: BLE001 - a recorder must survive any datagram
            self.garbage += 1
            return
        wall = time.monotonic()
        for msg in messages:
            if msg.get_type() == "BAD_DATA":
                self.garbage += 1
                continue
            if msg.get_srcComponent() != 1:  # autopilots only
                continue
            self._addr[msg.get_srcSystem()] = addr
            self._on_message(msg, wall)
        self._changed.set()

    def _on_message(self, msg, wall: float) -> None:
        sysid = msg.get_srcSystem()
        log = self.vehicles.setdefault(sysid, VehicleLog(sysid))
        kind = msg.get_type()
        if kind in _STAMPED:
            log.stamps.append((wall, msg.time_boot_ms / 1000.0))
        if kind == "HEARTBEAT":
            log.heartbeats += 1
            name = mode_name(msg.custom_mode)
            armed = bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
            if name != log.last_mode:
                log.mode_changes.append((wall, name))
                log.last_mode = name
            if not log.armed_changes or log.armed_changes[-1][1] != armed:
                log.armed_changes.append((wall, armed))
            log.armed = armed
        elif kind == "LOCAL_POSITION_NED":
            x, y, z = ned_to_enu(msg.x, msg.y, msg.z)
            log.positions.append((msg.time_boot_ms / 1000.0, x, y, z))
        elif kind == "STATUSTEXT":
            text = msg.text if isinstance(msg.text, str) else msg.text.decode(errors="replace")
            log.statustexts.append((wall, msg.severity, text.rstrip("\x00")))
        elif kind == "ADSB_VEHICLE":
            callsign = msg.callsign if isinstance(msg.callsign, str) else msg.callsign.decode(errors="replace")
            log.adsb.append(AdsbReport(wall, callsign.rstrip("\x00").strip(), msg.lat / 1e7, msg.lon / 1e7,
                                       msg.heading / 100.0, msg.hor_velocity / 100.0))
        elif kind == "EXTENDED_SYS_STATE":
            log.landed_state = msg.landed_state
        elif kind == "BATTERY_STATUS":
            log.battery_pct = None if msg.battery_remaining < 0 else float(msg.battery_remaining)
        elif kind == "MISSION_COUNT":
            self._mission_count[sysid] = msg.count
        elif kind == "MISSION_ITEM_INT":
            self._mission_items.setdefault(sysid, {})[msg.seq] = msg

    def _on_tap_datagram(self, data: bytes, addr) -> None:
        parser = self._tap_parsers.get(addr)
        if parser is None:
            parser = self._tap_parsers[addr] = mavlink.MAVLink(None)
            parser.robust_parsing = True
        try:
            messages = parser.parse_buffer(data) or []
        except Exception:  # noqa: BLE001
            return
        for msg in messages:
            kind = msg.get_type()
            sysid = msg.get_srcSystem()
            if kind == "LOCAL_POSITION_NED" and sysid in self.vehicles:
                x, y, z = ned_to_enu(msg.x, msg.y, msg.z)
                self.vehicles[sysid].api_positions.append((msg.time_boot_ms / 1000.0, x, y, z))
            elif kind == "COMMAND_ACK":
                self._acks.append((sysid, msg.command, msg.result))
        self._changed.set()

    # -- queries ------------------------------------------------------------------------------

    def heard(self, system_id: int) -> bool:
        return system_id in self.vehicles and self.vehicles[system_id].heartbeats > 0

    def log(self, system_id: int) -> VehicleLog:
        if system_id not in self.vehicles:
            raise KeyError(f"no telemetry recorded from system {system_id}")
        return self.vehicles[system_id]

    async def wait_until(self, predicate: Callable[["TelemetryRecorder"], bool], *, timeout_s: float,
                         what: str = "condition") -> None:
        """Wait, event-driven, until ``predicate(self)`` holds; TimeoutError names ``what``."""
        try:
            async with asyncio.timeout(timeout_s):
                while not predicate(self):
                    self._changed.clear()
                    await self._changed.wait()
        except TimeoutError:
            raise TimeoutError(f"timed out after {timeout_s:g} s waiting for {what}") from None

    # -- talking back as a GCS ----------------------------------------------------------------

    def send(self, system_id: int, msg) -> None:
        """Send one message to a vehicle, to the address its GCS stream comes from."""
        if self._transport is None or system_id not in self._addr:
            raise RuntimeError(f"system {system_id} has not been heard on the GCS link")
        self._transport.sendto(msg.pack(self._encoder), self._addr[system_id])

    async def tap(self, system_id: int, address: tuple, *, timeout_s: float = 10.0) -> None:
        """Listen to vehicle ``system_id``'s API link too: its positions join the track.

        ``address`` is the vehicle's API socket (where its API datagrams come from). Returns
        once a position has come that way. The vehicle must have been heard on the GCS link.
        """
        if self._tap is None:
            loop = asyncio.get_running_loop()
            self._tap, _ = await loop.create_datagram_endpoint(
                lambda: _Protocol(self._on_tap_datagram), local_addr=(self.host, 0))
        self._tap_addr[system_id] = address
        hello = mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                                                  mavlink.MAV_STATE_ACTIVE, 3)
        log = self.log(system_id)
        n0 = len(log.api_positions)
        try:
            async with asyncio.timeout(timeout_s):
                while not await self._wait_for(lambda: len(log.api_positions) > n0, 0.3):
                    self._tap.sendto(hello.pack(self._encoder), address)
        except TimeoutError:
            raise TimeoutError(f"system {system_id}: nothing heard on its API link {address} "
                               f"in {timeout_s:g} s") from None

    async def command_via_tap(self, system_id: int, command: int, *params: float, timeout_s: float = 5.0) -> int:
        """Send a COMMAND_LONG on a tapped API link; the COMMAND_ACK result (resent until answered)."""
        if self._tap is None or system_id not in self._tap_addr:
            raise RuntimeError(f"system {system_id}: API link not tapped")
        p = [float(v) for v in params] + [0.0] * (7 - len(params))
        msg = mavlink.MAVLink_command_long_message(system_id, 1, command, 0, *p)
        n0 = len(self._acks)

        def answers() -> list[int]:
            return [result for sysid, cmd, result in self._acks[n0:] if sysid == system_id and cmd == command]
        try:
            async with asyncio.timeout(timeout_s):
                while True:
                    self._tap.sendto(msg.pack(self._encoder), self._tap_addr[system_id])
                    if await self._wait_for(lambda: bool(answers()), 0.3):
                        return answers()[0]
        except TimeoutError:
            raise TimeoutError(f"system {system_id}: no COMMAND_ACK for command {command} in {timeout_s:g} s") from None

    async def download_mission(self, system_id: int, *, timeout_s: float = 10.0) -> list[tuple[int, float, float, float]]:
        """The vehicle's mission as (command, lat_deg, lon_deg, alt_m) rows, via the mission protocol."""
        self._mission_count.pop(system_id, None)
        self._mission_items[system_id] = {}
        mt = mavlink.MAV_MISSION_TYPE_MISSION
        try:
            async with asyncio.timeout(timeout_s):
                while system_id not in self._mission_count:
                    self.send(system_id, mavlink.MAVLink_mission_request_list_message(system_id, 1, mt))
                    await self._wait_for(lambda: system_id in self._mission_count, 0.3)
                count = self._mission_count[system_id]
                items = self._mission_items[system_id]
                while len(items) < count:
                    seq = next(i for i in range(count) if i not in items)
                    self.send(system_id, mavlink.MAVLink_mission_request_int_message(system_id, 1, seq, mt))
                    await self._wait_for(lambda: seq in items, 0.3)
        except TimeoutError:
            raise TimeoutError(f"system {system_id}: mission download did not finish in {timeout_s:g} s") from None
        self.send(system_id, mavlink.MAVLink_mission_ack_message(system_id, 1, mavlink.MAV_MISSION_ACCEPTED, mt))
        return [(it.command, it.x / 1e7, it.y / 1e7, it.z) for it in (items[i] for i in range(count))]

    async def _wait_for(self, predicate: Callable[[], bool], seconds: float) -> bool:
        """Up to ``seconds`` for ``predicate()``, re-checked as datagrams arrive (resend pacing)."""
        try:
            async with asyncio.timeout(seconds):
                while not predicate():
                    self._changed.clear()
                    await self._changed.wait()
        except TimeoutError:
            return False
        return True
