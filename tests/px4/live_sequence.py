"""The characterisation sequence, live: one raw-MAVLink client that measures a PX4-like vehicle.

The steps of ``../shared/px4-sih/characterise.py`` that give a figure (arming at boot, auto-disarm,
climb, turn, yaw in place, over-speed, offboard loss to RTL and to Hold, OFFBOARD re-entry,
landing, the mode after landing), timed in the vehicle's own sim time (``time_boot_ms``) rather
than the client's wall clock: PX4 SITL at a speed factor and the stub at any speedup then fly the
same sequence, and a loaded machine that slows either one stretches the wall time, not the figures.

    figures = {}
    with LiveVehicle(port) as v:
        characterise(v, figures)   # {"turn.speed_m_s": 7.6, "loss.mode": "RTL", ...}
"""

from __future__ import annotations

import contextlib
import math
import select
import socket
import struct
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import common as L

from sim_bridge.vehicle.px4 import FlightMode, decode_custom_mode

SETPOINT_WALL_S = 0.05  # 20 Hz of wall time, as characterise.py streams
GCS_HEARTBEAT_WALL_S = 1.0
COMMAND_SENDS = 3
RCVBUF_BYTES = 4 << 20  # capped by net.core.rmem_max
MAGIC_V2 = 0xFD
WANTED_IDS = frozenset({
    L.MAVLINK_MSG_ID_HEARTBEAT, L.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, L.MAVLINK_MSG_ID_STATUSTEXT,
    L.MAVLINK_MSG_ID_COMMAND_ACK, L.MAVLINK_MSG_ID_PARAM_VALUE})
# PX4 sends these at 30-100 Hz of sim time (x4 in wall time at 4x); means over seconds need far fewer.
DECIMATED_IDS = frozenset({
    L.MAVLINK_MSG_ID_ATTITUDE, L.MAVLINK_MSG_ID_LOCAL_POSITION_NED, L.MAVLINK_MSG_ID_GLOBAL_POSITION_INT})
DECIMATE_WALL_S = 0.01
DRAIN_WALL_S = 0.05  # at most this long in one drain, so that every wait checks its deadline
BOOT_WALL_S = 90.0  # PX4's startup script on a loaded machine
MIN_SPEEDUP = 0.5  # a sim-time wait gives up after sim_s / MIN_SPEEDUP of wall time (plus a margin)
BODY_VELOCITY_YAWRATE = 0x5C7  # velocity + yaw rate, position / acceleration / yaw ignored
ON_GROUND = L.MAV_LANDED_STATE_ON_GROUND


Stream = tuple[float, float, float] | Callable[[], tuple[float, float, float]]


class SequenceError(AssertionError):
    """The vehicle did not do what the step waited for, in time."""


@dataclass
class LinkStats:
    """MAVLink 2 frames seen and lost (sequence-number gaps per sender), counted before parsing."""

    frames: int = 0
    lost: int = 0
    _seq: dict[tuple[int, int], int] = field(default_factory=dict)
    _parsed_at: dict[int, float] = field(default_factory=dict)

    def wanted(self, data: bytes, now: float) -> bytes:
        """The frames of ``data`` whose message ids the sequence reads, concatenated; the fast streams
        at most one per DECIMATE_WALL_S of wall time (``now``)."""
        out = []
        i = 0
        while i + 12 <= len(data) and data[i] == MAGIC_V2:
            size = 12 + data[i + 1] + (13 if data[i + 2] & 1 else 0)
            seq, sender = data[i + 4], (data[i + 5], data[i + 6])
            if sender in self._seq:
                self.lost += (seq - self._seq[sender] - 1) % 256
            self._seq[sender] = seq
            self.frames += 1
            msgid = int.from_bytes(data[i + 7:i + 10], "little")
            if msgid in DECIMATED_IDS:
                if now - self._parsed_at.get(msgid, -1.0) >= DECIMATE_WALL_S:
                    self._parsed_at[msgid] = now
                    out.append(data[i:i + size])
            elif msgid in WANTED_IDS:
                out.append(data[i:i + size])
            i += size
        return b"".join(out)

    @property
    def loss(self) -> float:
        return self.lost / max(1, self.frames + self.lost)


@dataclass(frozen=True)
class Sample:
    sim_s: float
    value: float


@dataclass
class VehicleState:
    sim_s: float = 0.0
    mode: tuple[int, int] | None = None
    armed: bool = False
    landed: int | None = None
    rel_alt_m: float | None = None
    ground_speed_m_s: float = 0.0
    yawspeed_deg_s: float = 0.0
    texts: list[str] = field(default_factory=list)


def mode_name(mode: tuple[int, int] | None) -> str:
    if mode is None:
        return "none"
    known = FlightMode.from_px4(*mode)
    return known.name if known is not None else f"{mode[0]}/{mode[1]}"


class LiveVehicle:
    """A blocking raw-MAVLink client (pymavlink's codec on its own socket) on a vehicle's API port; the
    vehicle sends first."""

    def __init__(self, port: int, host: str = "127.0.0.1"):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RCVBUF_BYTES)
        self.sock.bind((host, port))
        self.sock.setblocking(False)
        self.peer: tuple[str, int] | None = None  # the vehicle's address, from its first datagram
        self.mav = L.MAVLink(self, srcSystem=245, srcComponent=190)
        self.link = LinkStats()
        self.s = VehicleState()
        self.sysid: int | None = None
        self.acks: list[tuple[int, int]] = []
        self.params: dict[str, float] = {}
        self._last_hb = 0.0
        self._recording: dict[str, list[Sample]] | None = None
        self.landing: dict[str, list[Sample]] = {}  # the samples of the last landing

    def __enter__(self) -> LiveVehicle:
        return self

    def __exit__(self, *exc) -> None:
        self.sock.close()

    def write(self, frame: bytes) -> None:
        """The encoder's file: frames go to the vehicle once it has been heard."""
        if self.peer is not None:
            self.sock.sendto(frame, self.peer)

    # ------------------------------------------------------------ receiving
    def pump(self, wall_s: float) -> None:
        end = time.monotonic() + wall_s
        while True:
            now = time.monotonic()
            if now - self._last_hb >= GCS_HEARTBEAT_WALL_S:
                self.mav.heartbeat_send(L.MAV_TYPE_GCS, L.MAV_AUTOPILOT_INVALID, 0, 0, L.MAV_STATE_ACTIVE)
                self._last_hb = now
            if now >= end:
                return
            self._drain(min(0.01, end - now))

    def _drain(self, wait_s: float) -> None:
        """Every datagram waiting (after up to ``wait_s``), only the wanted messages parsed: PX4 SITL at
        4x sends ~1500 messages per wall second, more than pymavlink parses beside a loaded simulator."""
        if not select.select([self.sock], [], [], wait_s)[0]:
            return
        start = time.monotonic()
        now = start
        while now - start < DRAIN_WALL_S:
            try:
                data, self.peer = self.sock.recvfrom(65535)
            except BlockingIOError:
                return
            now = time.monotonic()
            wanted = self.link.wanted(data, now)
            if wanted:
                for msg in self.mav.parse_buffer(wanted) or ():
                    self._handle(msg)

    def _handle(self, msg) -> None:
        kind = msg.get_type()
        s = self.s
        if kind == "HEARTBEAT":
            if msg.get_srcComponent() != 1 or msg.autopilot == L.MAV_AUTOPILOT_INVALID:
                return
            self.sysid = self.sysid or msg.get_srcSystem()
            s.mode = decode_custom_mode(msg.custom_mode)
            s.armed = bool(msg.base_mode & L.MAV_MODE_FLAG_SAFETY_ARMED)
        elif kind == "ATTITUDE":
            s.sim_s = max(s.sim_s, msg.time_boot_ms / 1000.0)
            s.yawspeed_deg_s = math.degrees(msg.yawspeed)
            self._record("yawspeed_deg_s", s.yawspeed_deg_s)
        elif kind == "LOCAL_POSITION_NED":
            s.sim_s = max(s.sim_s, msg.time_boot_ms / 1000.0)
            s.ground_speed_m_s = math.hypot(msg.vx, msg.vy)
            self._record("ground_speed_m_s", s.ground_speed_m_s)
        elif kind == "GLOBAL_POSITION_INT":
            s.rel_alt_m = msg.relative_alt / 1000.0
            self._record("rel_alt_m", s.rel_alt_m)
        elif kind == "EXTENDED_SYS_STATE":
            s.landed = msg.landed_state
        elif kind == "STATUSTEXT":
            s.texts.append(msg.text)
        elif kind == "COMMAND_ACK":
            self.acks.append((msg.command, msg.result))
        elif kind == "PARAM_VALUE":
            self.params[msg.param_id.rstrip("\x00")] = msg.param_value

    def _record(self, key: str, value: float) -> None:
        if self._recording is not None:
            self._recording.setdefault(key, []).append(Sample(self.s.sim_s, value))

    # ------------------------------------------------------------ sending
    def setpoint(self, forward_m_s: float = 0.0, yawspeed_deg_s: float = 0.0, down_m_s: float = 0.0) -> None:
        self.mav.set_position_target_local_ned_send(
            0, self.sysid or 1, 1, L.MAV_FRAME_BODY_NED, BODY_VELOCITY_YAWRATE, 0, 0, 0,
            forward_m_s, 0.0, down_m_s, 0, 0, 0, 0, math.radians(yawspeed_deg_s))

    def command(self, cmd: int, *params: float, wall_s: float = 6.0) -> int:
        """The final COMMAND_ACK result (IN_PROGRESS skipped); SequenceError without one."""
        p = (list(params) + [0.0] * 7)[:7]
        n0 = len(self.acks)
        end = time.monotonic() + wall_s
        for confirmation in range(COMMAND_SENDS):  # resent unanswered, as MAVSDK does (UDP may drop either way)
            self.mav.command_long_send(self.sysid or 1, 1, cmd, confirmation, *p)
            resend = time.monotonic() + wall_s / COMMAND_SENDS
            while time.monotonic() < min(resend, end):
                self.pump(0.02)
                for c, result in self.acks[n0:]:
                    if c == cmd and result != L.MAV_RESULT_IN_PROGRESS:
                        return result
        raise SequenceError(f"no COMMAND_ACK for command {cmd} in {wall_s} s ({COMMAND_SENDS} sends)")

    def set_mode(self, mode: FlightMode) -> int:
        main, sub = mode.value
        return self.command(L.MAV_CMD_DO_SET_MODE, L.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main, sub)

    def param_set(self, name: str, value: float, int32: bool = False) -> None:
        """Set and confirm: by the echo, else by reading it back (a starved PX4 may drop the echo)."""
        wire = struct.unpack("<f", struct.pack("<i", int(value)))[0] if int32 else float(value)
        ptype = L.MAV_PARAM_TYPE_INT32 if int32 else L.MAV_PARAM_TYPE_REAL32
        for attempt in range(2 * COMMAND_SENDS):
            self.params.pop(name, None)
            if attempt % 2 == 0:
                self.mav.param_set_send(self.sysid or 1, 1, name.encode(), wire, ptype)
            else:
                self.mav.param_request_read_send(self.sysid or 1, 1, name.encode(), -1)
            end = time.monotonic() + 1.5
            while time.monotonic() < end and name not in self.params:
                self.pump(0.02)
            if self.params.get(name) == wire:
                return
        raise SequenceError(f"PARAM_SET {name}={value}: neither echoed nor read back")

    # ------------------------------------------------------------ waiting in sim time
    def wait(self, pred: Callable[[], bool], sim_s: float, what: str, stream: Stream | None = None,
             wall_s: float | None = None) -> float:
        """Pump until ``pred``, streaming ``stream`` (forward, yawspeed, down; or a function giving them) if
        given; the sim time then."""
        t0 = self.s.sim_s
        wall0 = time.monotonic()
        wall_end = wall0 + (sim_s / MIN_SPEEDUP + 10.0 if wall_s is None else wall_s)
        next_sp = 0.0
        while not pred():
            now = time.monotonic()
            if self.s.sim_s - t0 > sim_s or now > wall_end:
                raise SequenceError(f"{what}: not within {sim_s} s sim ({self.s.sim_s - t0:.1f} s sim, "
                                    f"{now - wall0:.1f} s wall; mode {mode_name(self.s.mode)}, "
                                    f"armed {self.s.armed}, alt {self.s.rel_alt_m}; texts {self.s.texts[-5:]})")
            if stream is not None and now >= next_sp:
                self.setpoint(*(stream() if callable(stream) else stream))
                next_sp = now + SETPOINT_WALL_S
            self.pump(min(0.01, SETPOINT_WALL_S))
        return self.s.sim_s

    @contextlib.contextmanager
    def recording(self) -> Iterator[dict[str, list[Sample]]]:
        """The samples received inside the block, by quantity."""
        self._recording = {}
        try:
            yield self._recording
        finally:
            self._recording = None

    def run_for(self, sim_s: float, stream: Stream | None = None) -> dict[str, list[Sample]]:
        """``sim_s`` of sim time (streaming ``stream`` if given); the samples received meanwhile."""
        t_end = self.s.sim_s + sim_s
        with self.recording() as samples:
            self.wait(lambda: self.s.sim_s >= t_end, sim_s + 1.0, f"{sim_s} s of sim time", stream)
        return samples

    def in_mode(self, mode: FlightMode) -> Callable[[], bool]:
        return lambda: self.s.mode == mode.value


def mean_after(samples: list[Sample], t_from: float) -> float:
    """The mean of the samples from sim time ``t_from`` on: a steady value, not one noisy sample."""
    tail = [x.value for x in samples if x.sim_s >= t_from]
    if not tail:
        raise SequenceError(f"no samples after {t_from:.1f} s sim")
    return sum(tail) / len(tail)


def steady(samples: dict[str, list[Sample]], key: str, settle_s: float) -> float:
    first = samples[key][0].sim_s
    return mean_after(samples[key], first + settle_s)


# ---------------------------------------------------------------- the sequence ---------------
TURN = (10.0, -19.1, 0.0)  # forward m/s, yawspeed deg/s (CCW), down m/s: the mission's v and v/r
YAW_IN_PLACE = (0.0, 90.0, 0.0)
OVERSPEED = (15.0, 0.0, 0.0)  # above MPC_XY_VEL_MAX
STILL = (0.0, 0.0, 0.0)
LAND_FROM_M = 20.0  # the landing is timed from this altitude down
LAND_START_M = 20.8  # the altitude commanded before LAND: above LAND_FROM_M whatever Hold drifts
NAN = math.nan
FIGURES = (
    "boot.sim_rate", "boot.arm_refused_until_s", "boot.arm_accepted_s", "boot.auto_disarm_s", "climb.to_19m_s",
    "turn.speed_m_s", "turn.yawspeed_deg_s", "yaw_in_place.deg_s", "overspeed.speed_m_s",
    "loss.mode", "loss.after_s", "loss.reentry_mode", "loss_hold.mode", "loss_hold.after_s", "loss_hold.reentry_mode",
    "land.duration_s", "land.final_mode")


def arm_at_boot(v: LiveVehicle, fig: dict) -> float:
    """Arm from the first heartbeat on, retrying every 0.25 s sim; the sim time it was accepted."""
    v.wait(lambda: v.s.sim_s > 0, math.inf, "the first telemetry", wall_s=BOOT_WALL_S)
    sim0, wall0 = v.s.sim_s, time.monotonic()
    # A starved PX4 streams telemetry long before its startup script gets to the heartbeat.
    v.wait(lambda: v.sysid is not None, math.inf, "the first heartbeat", wall_s=BOOT_WALL_S)
    refused = 0
    fig["boot.arm_refused_until_s"] = 0.0
    while True:
        try:
            if v.command(L.MAV_CMD_COMPONENT_ARM_DISARM, 1, wall_s=1.5) == L.MAV_RESULT_ACCEPTED:
                break
        except SequenceError:
            pass  # PX4's commander may not answer in its first seconds
        refused += 1
        fig["boot.arm_refused_until_s"] = v.s.sim_s
        if v.s.sim_s > 30.0:
            raise SequenceError(f"arming refused for 30 s sim ({refused} tries)")
        v.run_for(0.25)
    fig["boot.arm_accepted_s"] = v.s.sim_s
    fig["boot.sim_rate"] = (v.s.sim_s - sim0) / max(1e-3, time.monotonic() - wall0)
    return v.s.sim_s


def characterise(v: LiveVehicle, fig: dict[str, float | str]) -> None:
    """Fly the sequence, filling ``fig`` with the figures by name (sim seconds, m/s, deg/s, mode names)
    as they are measured (a failed step leaves the ones before it)."""
    arm_at_boot(v, fig)
    # Both ends as the heartbeat shows them: a late ack under load would shift only one.
    t_arm = v.wait(lambda: v.s.armed, 5.0, "a heartbeat showing armed")
    t_disarm = v.wait(lambda: not v.s.armed, 25.0, "auto-disarm without take-off")
    fig["boot.auto_disarm_s"] = t_disarm - t_arm

    v.param_set("MIS_TAKEOFF_ALT", LAND_FROM_M)
    if v.command(L.MAV_CMD_COMPONENT_ARM_DISARM, 1) != L.MAV_RESULT_ACCEPTED:
        raise SequenceError("arming for take-off refused")
    if v.command(L.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, NAN) != L.MAV_RESULT_ACCEPTED:
        raise SequenceError("take-off refused")
    t0 = v.s.sim_s
    fig["climb.to_19m_s"] = v.wait(lambda: (v.s.rel_alt_m or 0.0) > 19.0, 60.0, "19 m") - t0
    v.wait(v.in_mode(FlightMode.HOLD), 30.0, "HOLD after take-off")
    v.run_for(2.0)

    v.run_for(1.0, STILL)
    v.set_mode(FlightMode.OFFBOARD)
    v.wait(v.in_mode(FlightMode.OFFBOARD), 5.0, "OFFBOARD in the air", STILL)
    turn = v.run_for(12.0, TURN)
    fig["turn.speed_m_s"] = steady(turn, "ground_speed_m_s", 6.0)
    fig["turn.yawspeed_deg_s"] = steady(turn, "yawspeed_deg_s", 6.0)
    fig["yaw_in_place.deg_s"] = steady(v.run_for(4.0, YAW_IN_PLACE), "yawspeed_deg_s", 2.0)
    fig["overspeed.speed_m_s"] = steady(v.run_for(8.0, OVERSPEED), "ground_speed_m_s", 5.0)
    v.run_for(4.0, STILL)

    for key, action in (("loss", 0), ("loss_hold", 5)):
        if action:
            v.param_set("COM_OBL_RC_ACT", action, int32=True)
            v.run_for(1.0, STILL)
        t_last = v.s.sim_s
        t_mode = v.wait(lambda: v.s.mode != FlightMode.OFFBOARD.value, 30.0, f"{key}: the offboard-loss failsafe")
        fig[f"{key}.mode"] = mode_name(v.s.mode)
        fig[f"{key}.after_s"] = t_mode - t_last
        v.run_for(1.0)
        v.run_for(4.0, STILL)  # no mode command: PX4 re-enters OFFBOARD by itself
        fig[f"{key}.reentry_mode"] = mode_name(v.s.mode)
        if v.s.mode != FlightMode.OFFBOARD.value:
            v.set_mode(FlightMode.OFFBOARD)
            v.wait(v.in_mode(FlightMode.OFFBOARD), 5.0, "OFFBOARD after the failsafe", STILL)
    v.param_set("COM_OBL_RC_ACT", 0, int32=True)

    land_from(v, fig)


def land_from(v: LiveVehicle, fig: dict) -> None:
    """Climb or descend to LAND_START_M in OFFBOARD, Hold, LAND: the time from LAND_FROM_M to the ground
    (landed_state ON_GROUND), and the mode after the disarm."""
    def error_m() -> float:
        return (v.s.rel_alt_m or 0.0) - LAND_START_M

    def toward() -> tuple[float, float, float]:
        return 0.0, 0.0, max(-2.0, min(2.0, 0.8 * error_m()))
    v.wait(lambda: abs(error_m()) < 0.3, 60.0, f"OFFBOARD to {LAND_START_M} m", toward)
    v.set_mode(FlightMode.HOLD)
    v.wait(v.in_mode(FlightMode.HOLD), 5.0, "HOLD before landing", STILL)
    v.run_for(2.0)
    if v.command(L.MAV_CMD_NAV_LAND, 0, 0, 0, NAN, NAN, NAN, NAN) != L.MAV_RESULT_ACCEPTED:
        raise SequenceError("LAND refused")
    with v.recording() as v.landing:
        t_from = v.wait(lambda: (v.s.rel_alt_m or 0.0) <= LAND_FROM_M, 30.0, f"down to {LAND_FROM_M} m")
        fig["land.duration_s"] = v.wait(lambda: v.s.landed == ON_GROUND, 90.0, "landed") - t_from
    v.wait(lambda: not v.s.armed, 20.0, "disarmed after landing")
    v.run_for(2.0)
    fig["land.final_mode"] = mode_name(v.s.mode)
