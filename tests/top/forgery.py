"""A forger for the link tests: HEARTBEATs claiming HOLD and GLOBAL_POSITION_INTs 5 km east of a
mission's origin, as system 1, sent from a new UDP socket every 0.1 s (wall) by each encoder in
turn (an unsigned one, or one signing with the wrong key)."""

from __future__ import annotations

import socket
import time
from pathlib import Path

from pymavlink.dialects.v20 import common as mavlink

from uav_model import frames
from uav_model.mission import load_mission

PX4_HOLD = (4 << 16) | (3 << 24)  # AUTO.LOITER: what a forger would claim


def forge_as_system_1(port: int, mission_path: Path, seconds: float,
                      encoders: list[mavlink.MAVLink] | None = None) -> tuple[tuple[str, int], int]:
    """Send for ``seconds`` to 127.0.0.1:``port``; the socket's own address and the frames sent."""
    lat, lon, _ = frames.local_to_geodetic(load_mission(mission_path).origin, 5000.0, 0.0, 0.0)
    encoders = encoders or [mavlink.MAVLink(None, 1, 1)]
    sent = 0
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        end = time.monotonic() + seconds
        t_ms = 0
        while time.monotonic() < end:
            for enc in encoders:
                hb = enc.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4,
                                          mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_SAFETY_ARMED,
                                          PX4_HOLD, mavlink.MAV_STATE_ACTIVE)
                pos = enc.global_position_int_encode(t_ms, int(lat * 1e7), int(lon * 1e7), 500_000, 5_000, 0, 0, 0, 0)
                for msg in (hb, pos):
                    sock.sendto(msg.pack(enc), ("127.0.0.1", port))
                    sent += 1
            t_ms += 100
            time.sleep(0.1)
        return sock.getsockname(), sent
