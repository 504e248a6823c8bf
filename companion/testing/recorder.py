"""A GCS-side telemetry recorder: listens like QGroundControl on a UDP port and records every
vehicle it hears, so scenario tests assert on what the vehicles *report*, not on what the
companion believes about itself.

It is asyncio and never blocks: datagrams arrive through a ``DatagramProtocol``, are decoded by
one pymavlink parser per sender, and are appended to per-vehicle logs. Waiting is event-driven
(:meth:`TelemetryRecorder.wait_until`) with a timeout on every wait.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from companion.frames import ned_to_enu
from companion.planning.metrics import Track
from sim_bridge.px4 import FlightMode, decode_custom_mode

GCS_SYSTEM_ID = 255
GCS_COMPONENT_ID = 190  # MAV_COMP_ID_MISSIONPLANNER, what QGroundControl uses


def mode_name(custom_mode: int) -> str:
    """PX4 custom_mode word -> the stub's FlightMode name (``"OFFBOARD"``, ``"HOLD"``...)."""
    main, sub = decode_custom_mode(custom_mode)
    mode = FlightMode.from_px4(main, sub)
    return mode.name if mode is not None else f"PX4({main},{sub})"


@dataclass
class VehicleLog:
    """Everything one vehicle said, in arrival order. Times are the vehicle's sim time (s)."""

    system_id: int
    modes: list[str] = field(default_factory=list)  # mode sequence, consecutive repeats folded
    mode_times_s: list[float] = field(default_factory=list)  # sim time of the last sample at each change
    armed_history: list[bool] = field(default_factory=list)
    last_mode: str | None = None
    armed: bool = False
    heartbeats: int = 0
    t_s: list[float] = field(default_factory=list)
    x_m: list[float] = field(default_factory=list)
    y_m: list[float] = field(default_factory=list)
    z_m: list[float] = field(default_factory=list)
    statustext: list[str] = field(default_factory=list)
    adsb: dict[str, list[tuple[float, float, float]]] = field(default_factory=dict)  # callsign -> (wall, lat, lon)
    landed_state: int | None = None
    battery_pct: float | None = None

    def track(self, since_mode: str | None = None) -> Track:
        """The ENU ground track from LOCAL_POSITION_NED, strictly increasing in sim time.

        ``since_mode="OFFBOARD"`` starts it at the first sample of the first OFFBOARD stretch,
        so flight time counts from departure, not from power-on and take-off.
        """
        t = np.asarray(self.t_s)
        start = 0
        if since_mode is not None:
            if since_mode not in self.modes:
                raise ValueError(f"system {self.system_id} never reported mode {since_mode}")
            t_mode = self.mode_times_s[self.modes.index(since_mode)]
            start = int(np.searchsorted(t, t_mode, side="left"))
        t = t[start:]
        # Late or duplicated datagrams (lossy links) are dropped, not re-sorted into the past.
        prev_max = np.concatenate([[-np.inf], np.maximum.accumulate(t)[:-1]]) if len(t) else t
        keep = t > prev_max
        return Track(t[keep], np.asarray(self.x_m)[start:][keep], np.asarray(self.y_m)[start:][keep])

    @property
    def position_enu_m(self) -> tuple[float, float] | None:
        return (self.x_m[-1], self.y_m[-1]) if self.x_m else None


class _Protocol(asyncio.DatagramProtocol):
    def __init__(self, recorder: "TelemetryRecorder"):
        self.recorder = recorder

    def datagram_received(self, data: bytes, addr) -> None:
        self.recorder._on_datagram(data, addr)


class TelemetryRecorder:
    """Record every vehicle heard on a GCS UDP port.

    >>> async with TelemetryRecorder(port=0) as rec:     # port 0: pick a free one
    ...     await rec.wait_until(lambda r: r.heard(1), timeout_s=5)
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
        self._encoder = mavlink.MAVLink(None, srcSystem=GCS_SYSTEM_ID, srcComponent=GCS_COMPONENT_ID)
        self._encoder.robust_parsing = True

    async def __aenter__(self) -> "TelemetryRecorder":
        loop = asyncio.get_running_loop()
        self._transport, _ = await loop.create_datagram_endpoint(
            lambda: _Protocol(self), local_addr=(self.host, self.port))
        self.port = self._transport.get_extra_info("sockname")[1]
        return self

    async def __aexit__(self, *exc) -> None:
        if self._transport is not None:
            self._transport.close()
            self._transport = None

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
        for msg in messages:
            if msg.get_type() == "BAD_DATA":
                self.garbage += 1
                continue
            self._addr[msg.get_srcSystem()] = addr
            self._on_message(msg)
        self._changed.set()

    def _on_message(self, msg) -> None:
        sysid = msg.get_srcSystem()
        if msg.get_srcComponent() != 1:
            return
        log = self.vehicles.setdefault(sysid, VehicleLog(sysid))
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            log.heartbeats += 1
            name = mode_name(msg.custom_mode)
            armed = bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
            if name != log.last_mode:
                log.modes.append(name)
                log.mode_times_s.append(log.t_s[-1] if log.t_s else 0.0)
                log.last_mode = name
            if not log.armed_history or log.armed_history[-1] != armed:
                log.armed_history.append(armed)
            log.armed = armed
        elif kind == "LOCAL_POSITION_NED":
            x, y, z = ned_to_enu(msg.x, msg.y, msg.z)
            log.t_s.append(msg.time_boot_ms / 1000.0)
            log.x_m.append(x)
            log.y_m.append(y)
            log.z_m.append(z)
        elif kind == "STATUSTEXT":
            log.statustext.append(msg.text)
        elif kind == "ADSB_VEHICLE":
            callsign = msg.callsign.rstrip("\x00").strip() if isinstance(msg.callsign, str) else str(msg.callsign)
            log.adsb.setdefault(callsign, []).append((time.monotonic(), msg.lat / 1e7, msg.lon / 1e7))
        elif kind == "EXTENDED_SYS_STATE":
            log.landed_state = msg.landed_state
        elif kind == "BATTERY_STATUS":
            log.battery_pct = None if msg.battery_remaining < 0 else float(msg.battery_remaining)
        elif kind == "MISSION_COUNT":
            self._mission_count[sysid] = msg.count
        elif kind == "MISSION_ITEM_INT":
            self._mission_items.setdefault(sysid, {})[msg.seq] = msg

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

    async def download_mission(self, system_id: int, *, timeout_s: float = 10.0) -> list[tuple[int, float, float, float]]:
        """The vehicle's mission as (command, lat_deg, lon_deg, alt_m) rows, via the mission protocol."""
        self._mission_count.pop(system_id, None)
        self._mission_items[system_id] = {}
        mt = mavlink.MAV_MISSION_TYPE_MISSION
        async with asyncio.timeout(timeout_s):
            while system_id not in self._mission_count:
                self.send(system_id, mavlink.MAVLink_mission_request_list_message(system_id, 1, mt))
                await self._wait_changed(0.3)
            count = self._mission_count[system_id]
            items = self._mission_items[system_id]
            while len(items) < count:
                seq = next(i for i in range(count) if i not in items)
                self.send(system_id, mavlink.MAVLink_mission_request_int_message(system_id, 1, seq, mt))
                await self._wait_changed(0.3)
            self.send(system_id, mavlink.MAVLink_mission_ack_message(system_id, 1, mavlink.MAV_MISSION_ACCEPTED, mt))
        return [(it.command, it.x / 1e7, it.y / 1e7, it.z) for it in (items[i] for i in range(count))]

    async def _wait_changed(self, seconds: float) -> None:
        self._changed.clear()
        try:
            async with asyncio.timeout(seconds):
                await self._changed.wait()
        except TimeoutError:
            pass

