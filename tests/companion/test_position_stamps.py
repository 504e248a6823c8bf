"""Each position MAVSDK hands over is matched to the GLOBAL_POSITION_INT it came from, and so to
the vehicle's own time stamp, from real pymavlink frames (MAVLink 1 and 2, truncated payloads,
signed frames, several frames per datagram, other system ids)."""

from __future__ import annotations

import struct

from pymavlink.dialects.v20 import common as mavlink

from companion.vehicle.position_stamps import PositionStamps


def _frame(t_ms: int, lat: int, lon: int, rel_mm: int, *, sysid: int = 1, v1: bool = False,
           key: bytes | None = None, vx: int = 0) -> bytes:
    mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=1)
    if key is not None:
        mav.signing.secret_key = key
        mav.signing.link_id = 0
        mav.signing.timestamp = 1
        mav.signing.sign_outgoing = True
    msg = mavlink.MAVLink_global_position_int_message(t_ms, lat, lon, rel_mm + 480_000, rel_mm, vx, 0, 0, 0)
    return msg.pack(mav, force_mavlink1=v1)


def _as_mavsdk(lat: int, lon: int, rel_mm: int) -> tuple[float, float, float]:
    """What MAVSDK's Position holds: degrees and metres, as doubles and a float."""
    return lat * 1e-7, lon * 1e-7, struct.unpack("<f", struct.pack("<f", rel_mm * 1e-3))[0]


def test_a_position_gets_the_stamp_of_the_frame_it_came_from_in_every_framing():
    stamps = PositionStamps(system_id=1)
    # MAVLink 2 with every trailing field zero (truncated), MAVLink 1, signed, and two in one datagram.
    stamps.record(_frame(1000, 473977420, 85455940, 20_000))
    stamps.record(_frame(1100, 473977421, 85455941, 20_010, v1=True))
    stamps.record(_frame(1200, 473977422, 85455942, 20_020, key=bytes(range(32)), vx=-350))
    stamps.record(_frame(1300, 473977423, 85455943, 20_030) + _frame(1400, 473977424, 85455944, 20_040))
    stamps.record(_frame(1350, 473977423, 85455943, 20_030, sysid=2))  # another vehicle's: not ours
    got = [stamps.lookup(*_as_mavsdk(473977420 + i, 85455940 + i, 20_000 + 10 * i)) for i in range(5)]
    assert got == [1.0, 1.1, 1.2, 1.3, 1.4]


def test_a_vehicle_standing_still_gets_each_stamp_in_turn_and_an_unseen_position_none():
    stamps = PositionStamps(system_id=1)
    for t_ms in (5000, 5100, 5200, 5300):
        stamps.record(_frame(t_ms, 473977420, 85455940, 0))
    here = _as_mavsdk(473977420, 85455940, 0)
    assert [stamps.lookup(*here) for _ in range(2)] == [5.0, 5.1]
    # MAVSDK skipped 5.2 (a full callback queue): the next delivery matches the oldest still unmatched.
    assert stamps.lookup(*here) == 5.2
    assert stamps.lookup(*_as_mavsdk(473977999, 85455940, 0)) is None
    assert stamps.lookup(*here) == 5.3
    assert stamps.lookup(*here) is None  # every stamp used: never the same one twice


def test_only_the_newest_positions_are_kept():
    stamps = PositionStamps(system_id=1, keep=3)
    for i in range(5):
        stamps.record(_frame(1000 + i, 473977420 + i, 85455940, 0))
    assert stamps.lookup(*_as_mavsdk(473977420, 85455940, 0)) is None
    assert stamps.lookup(*_as_mavsdk(473977424, 85455940, 0)) == 1.004


def _traffic(icao: int, lat: int, lon: int, *, sysid: int = 1) -> bytes:
    mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=1)
    return mav.adsb_vehicle_encode(icao, lat, lon, mavlink.ADSB_ALTITUDE_TYPE_GEOMETRIC, 0, 9000, 400, 0, b"shuttle",
                                   mavlink.ADSB_EMITTER_TYPE_POINT_OBSTACLE, 0, 0x17, 0).pack(mav)


def _attitude(t_ms: int, *, sysid: int = 1) -> bytes:
    mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=1)
    return mavlink.MAVLink_attitude_message(t_ms, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0).pack(mav)


def test_a_traffic_report_gets_the_vehicle_clock_of_the_frame_sent_before_it():
    stamps = PositionStamps(system_id=1)
    stamps.record(_traffic(0x500, 473977420, 85455940))  # before any clock: never stamped
    stamps.record(_frame(2000, 473977420, 85455940, 0))
    stamps.record(_traffic(0x501, 473977500, 85456000) + _traffic(0x502, 473977600, 85456100))  # one instant
    stamps.record(_attitude(2050))
    stamps.record(_attitude(2070, sysid=2))  # another vehicle's clock: not ours
    stamps.record(_traffic(0x501, 473977510, 85456010))
    stamps.record(_traffic(0x503, 473977700, 85456200, sysid=2))  # relayed by another system: not ours
    assert stamps.lookup_traffic(0x500, 47.3977420, 8.5455940) is None
    assert stamps.lookup_traffic(0x501, 473977500 * 1e-7, 85456000 * 1e-7) == 2.0
    assert stamps.lookup_traffic(0x502, 473977600 * 1e-7, 85456100 * 1e-7) == 2.0  # the same instant
    assert stamps.lookup_traffic(0x501, 473977510 * 1e-7, 85456010 * 1e-7) == 2.05
    assert stamps.lookup_traffic(0x503, 473977700 * 1e-7, 85456200 * 1e-7) is None
    assert stamps.traffic_missed == 2 and stamps.missed == 0  # positions are counted apart
