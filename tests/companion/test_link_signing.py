"""MAVLink 2 signing in the link guard, checked against pymavlink's own signing.

What the guard signs, pymavlink accepts with the key (and refuses with another); what pymavlink
signs with the key, the guard passes; unsigned frames, other keys and replays it drops. Over
real UDP, a guard with a key relays MAVSDK's frames signed and the autopilot's only when signed.
"""

from __future__ import annotations

import asyncio
import hashlib
import socket

from pymavlink.dialects.v20 import common as mavlink

from companion.vehicle.link_guard import LOOPBACK, guarded_port
from companion.vehicle.link_probe import MAVLINK_IFLAG_SIGNED
from companion.vehicle.link_signing import LinkSigner
from uav_model.signing_key import signing_timestamp

KEY = hashlib.sha256(b"correct horse").digest()
OTHER = hashlib.sha256(b"battery staple").digest()


def _encoder(system_id: int = 245, key: bytes | None = None, timestamp: int | None = None,
             mavlink1: bool = False) -> mavlink.MAVLink:
    enc = mavlink.MAVLink(None, system_id, 190)
    if key is not None:
        enc.signing.secret_key, enc.signing.sign_outgoing = key, True
        enc.signing.timestamp = signing_timestamp() if timestamp is None else timestamp
    if mavlink1:
        enc.WIRE_PROTOCOL_VERSION = "1.0"
    return enc


def _setpoint(enc: mavlink.MAVLink, x: float, target: int = 1, mavlink1: bool = False) -> bytes:
    msg = enc.set_position_target_local_ned_encode(0, target, 1, mavlink.MAV_FRAME_BODY_NED, 0xDC7,
                                                   x, 0, 0, 1.0, 0, 0, 0, 0, 0, 0, 0.1)
    return msg.pack(enc, force_mavlink1=mavlink1)


def _heartbeat(enc: mavlink.MAVLink) -> bytes:
    return enc.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, 0, 0,
                                mavlink.MAV_STATE_ACTIVE).pack(enc)


def _reader(key: bytes) -> mavlink.MAVLink:
    dec = mavlink.MAVLink(None)
    dec.robust_parsing = True
    dec.signing.secret_key = key
    dec.signing.timestamp = signing_timestamp()
    return dec


def test_what_the_guard_signs_pymavlink_accepts_with_the_key_only():
    signer = LinkSigner(KEY)
    enc = _encoder()
    datagrams = [signer.sign(_setpoint(enc, float(i))) for i in range(5)]
    datagrams.append(signer.sign(_setpoint(enc, 9.0, mavlink1=True)))  # upgraded to MAVLink 2
    good, bad = _reader(KEY), _reader(OTHER)
    read = [m for d in datagrams for m in good.parse_buffer(d) or []]
    assert [m.get_type() for m in read] == ["SET_POSITION_TARGET_LOCAL_NED"] * 6, read
    assert [m.x for m in read] == [0.0, 1.0, 2.0, 3.0, 4.0, 9.0]
    assert all(m.get_srcSystem() == 245 and m.get_srcComponent() == 190 for m in read)
    assert good.signing.goodsig_count == 6 and good.signing.badsig_count == 0
    stamps = [int.from_bytes(d[-12:-6], "little") for d in datagrams]
    assert stamps == sorted(set(stamps)) and abs(stamps[0] - signing_timestamp()) < 10 * 100_000
    assert all(d[0] == 0xFD and d[2] & MAVLINK_IFLAG_SIGNED for d in datagrams)
    assert [m.get_type() for d in datagrams for m in bad.parse_buffer(d) or []] == ["BAD_DATA"] * 6
    assert (signer.signed, signer.upgraded, signer.unsignable) == (6, 1, 0)


def test_frames_the_guard_cannot_sign_are_left_out_and_counted():
    signer = LinkSigner(KEY)
    good = _setpoint(_encoder(), 1.0)
    corrupt = bytearray(good)
    corrupt[12] ^= 0xFF  # a payload byte: the CRC no longer matches
    unknown = bytes([0xFD, 1, 0, 0, 0, 245, 190, 0x39, 0x30, 0x00, 7, 0, 0])  # message 12345: no CRC seed known
    out = signer.sign(bytes(corrupt) + unknown + good)
    assert [m.x for m in _reader(KEY).parse_buffer(out) or []] == [1.0]
    assert (signer.signed, signer.unsignable) == (1, 2)


def test_the_guard_passes_signed_frames_and_drops_unsigned_other_keys_and_replays():
    signer = LinkSigner(KEY)
    autopilot = _encoder(1, KEY)
    signed = [_heartbeat(autopilot) for _ in range(3)]
    passed, signers, refused = signer.check(signed[0] + signed[1])
    assert passed == signed[0] + signed[1] and signers == {1} and refused == []
    assert signer.check(signed[1])[0] == b""  # replayed: its timestamp is not newer
    assert signer.check(_heartbeat(_encoder(1)))[0] == b""  # unsigned HEARTBEAT: refused (it carries the mode)
    assert signer.check(_heartbeat(_encoder(1, OTHER)))[0] == b""
    radio = _encoder(1)
    status = radio.radio_status_encode(200, 190, 100, 20, 10, 0, 0).pack(radio)
    assert signer.check(status)[0] == status  # a radio's own report may come unsigned
    assert signer.check(signed[2])[0] == signed[2]
    assert (signer.verified, signer.refused) == (3, 3)
    kinds = [r.signed for r in signer.check(_heartbeat(_encoder(1)) + _heartbeat(_encoder(1, OTHER)))[2]]
    assert kinds == [False, True]


def test_a_forged_frame_with_a_far_future_timestamp_does_not_lock_the_autopilot_out():
    signer = LinkSigner(KEY)
    forged = bytearray(_heartbeat(_encoder(1, OTHER, timestamp=(1 << 48) - 10)))
    assert signer.check(bytes(forged))[0] == b""
    real = _heartbeat(_encoder(1, KEY))
    assert signer.check(real)[0] == real  # the forgery did not move the stream's clock


def test_an_old_new_stream_is_refused():
    signer = LinkSigner(KEY)
    stale = _heartbeat(_encoder(1, KEY, timestamp=signing_timestamp() - 120 * 100_000))
    assert signer.check(stale)[0] == b""


def _udp(port: int = 0) -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind((LOOPBACK, port))
    sock.settimeout(2.0)
    return sock


def test_a_guard_with_a_key_signs_mavsdk_frames_and_relays_only_signed_ones_over_udp():
    async def main():
        with _udp() as probe:
            port = probe.getsockname()[1]
        async with guarded_port(LOOPBACK, port, system_id=1, vehicle="a", signing_key=KEY) as guard:
            with _udp() as autopilot, _udp(guard.mavsdk_port) as mavsdk, _udp() as forger:
                autopilot_enc = _encoder(1, KEY)
                forger.sendto(_heartbeat(_encoder(1)), (LOOPBACK, port))  # unsigned: dropped, not the autopilot
                autopilot.sendto(_heartbeat(autopilot_enc), (LOOPBACK, port))
                hb, relay = mavsdk.recvfrom(65535)
                mavsdk.sendto(_setpoint(_encoder(), 3.0), relay)
                out, _ = autopilot.recvfrom(65535)
                await guard.first_word(1.0, "a")
                return hb, out, guard.autopilot, autopilot.getsockname(), guard.link_events(), guard.signing_problem

    hb, out, who, autopilot, events, problem = asyncio.run(main())
    assert hb[2] & MAVLINK_IFLAG_SIGNED  # relayed as it came
    assert [m.x for m in _reader(KEY).parse_buffer(out) or []] == [3.0]
    assert who == autopilot and problem is None
    assert events["signed_out"] == 1 and events["verified_in"] == 1 and events["signing_refused"] == 1
