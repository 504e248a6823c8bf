"""The in-process link's wire side: who the companion is on it, one codec per direction, and the
protocol tables (PX4 modes, COMMAND_ACK results, mission results) that both directions read."""

from __future__ import annotations

import struct
from types import MappingProxyType
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from companion.vehicle.port import FlightMode
from sim_bridge.vehicle.px4 import Px4AutoSubMode, Px4MainMode
from sim_bridge.vehicle.streams import API_RATES_HZ, StreamProfile

LINK = "api"  # the one link each in-process vehicle has: the companion's
PEER = "companion"
# The stub's API stream rates, in sim time only (a wall-clock cap would starve a fast sim), less
# the streams this link's one reader never reads: building them is a third of the telemetry cost.
UNREAD_STREAMS = frozenset({mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, mavlink.MAVLINK_MSG_ID_MISSION_CURRENT})
INPROCESS_MAX_RATE_HZ = 20.0  # PX4's 50-100 Hz attitude and position: the planner ticks at 2 Hz
INPROCESS_PROFILE = StreamProfile(
    MappingProxyType({k: min(hz, INPROCESS_MAX_RATE_HZ) for k, hz in API_RATES_HZ.items() if k not in UNREAD_STREAMS}),
    max_wall_rate_hz=0.0)
# SET_POSITION_TARGET_LOCAL_NED: body velocity + yaw rate (position, acceleration and yaw ignored).
BODY_VELOCITY_YAW_RATE_MASK = (
    mavlink.POSITION_TARGET_TYPEMASK_X_IGNORE | mavlink.POSITION_TARGET_TYPEMASK_Y_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_Z_IGNORE | mavlink.POSITION_TARGET_TYPEMASK_AX_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_AY_IGNORE | mavlink.POSITION_TARGET_TYPEMASK_AZ_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_YAW_IGNORE)

# PX4 (main, sub) modes of the port's flight modes; sub modes only mean something under AUTO.
PX4_MODES: dict[FlightMode, tuple[int, int]] = {
    FlightMode.READY: (Px4MainMode.AUTO, Px4AutoSubMode.READY),
    FlightMode.TAKEOFF: (Px4MainMode.AUTO, Px4AutoSubMode.TAKEOFF),
    FlightMode.HOLD: (Px4MainMode.AUTO, Px4AutoSubMode.LOITER),
    FlightMode.MISSION: (Px4MainMode.AUTO, Px4AutoSubMode.MISSION),
    FlightMode.RETURN_TO_LAUNCH: (Px4MainMode.AUTO, Px4AutoSubMode.RTL),
    FlightMode.LAND: (Px4MainMode.AUTO, Px4AutoSubMode.LAND),
    FlightMode.OFFBOARD: (Px4MainMode.OFFBOARD, Px4AutoSubMode.NONE),
    FlightMode.POSCTL: (Px4MainMode.POSCTL, Px4AutoSubMode.NONE),
}
MODES = {pair: mode for mode, pair in PX4_MODES.items()}
# COMMAND_ACK results under the names MAVSDK gives them, and whether a retry may help.
COMMAND_RESULTS: dict[int, tuple[str, bool]] = {
    mavlink.MAV_RESULT_TEMPORARILY_REJECTED: ("COMMAND_DENIED", False),
    mavlink.MAV_RESULT_DENIED: ("COMMAND_DENIED", False),
    mavlink.MAV_RESULT_UNSUPPORTED: ("UNSUPPORTED", False),
    mavlink.MAV_RESULT_FAILED: ("UNKNOWN", True),
}


def text_field(value: bytes | str) -> str:
    """A char[] field: bytes on a message object as built, str once parsed from the wire."""
    text = value.decode("ascii", "replace") if isinstance(value, bytes) else str(value)
    return text.split("\x00", 1)[0].strip()


def mission_result(code: int) -> str:
    entry = mavlink.enums["MAV_MISSION_RESULT"].get(code)
    return entry.name if entry is not None else f"MAV_MISSION_RESULT {code}"


def describe(msg: Any) -> str:
    """A mission-protocol reply that was not the one expected, for an error message."""
    if msg.get_type() == "MISSION_ACK":
        return mission_result(msg.type)
    return f"unexpected {msg.get_type()}"


class Codec:
    """One direction of the in-process link: packs with the sender's ids; with ``wire``, re-parses."""

    def __init__(self, system_id: int, component_id: int, wire: bool):
        self._encoder = mavlink.MAVLink(None, system_id, component_id)
        self._parser = mavlink.MAVLink(None, 0, 0) if wire else None
        if self._parser is not None:
            self._parser.robust_parsing = True

    @property
    def factory(self) -> mavlink.MAVLink:
        return self._encoder

    def carry(self, msg: Any) -> list[Any]:
        """What arrives at the other end: the packed message itself, or what the bytes parse to."""
        buf = msg.pack(self._encoder)  # sets the header (source ids, sequence) as on the wire
        self._encoder.seq = (self._encoder.seq + 1) % 256
        if self._parser is None:
            return [msg]
        return [m for m in self._parser.parse_buffer(buf) or [] if m.get_type() != "BAD_DATA"]



def int32_bits(value: float) -> float:
    """An INT32 parameter as PX4 sends it: the int's bytes read as a float."""
    return struct.unpack("<f", struct.pack("<i", int(round(value))))[0]


def param_value(msg: Any) -> float:
    """PARAM_VALUE's value, INT32 ones decoded bytewise (PX4)."""
    if int(msg.param_type) == mavlink.MAV_PARAM_TYPE_INT32:
        return float(struct.unpack("<i", struct.pack("<f", msg.param_value))[0])
    return float(msg.param_value)
