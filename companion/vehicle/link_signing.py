"""MAVLink 2 signing on a guarded link, for MAVSDK, which neither signs nor checks signatures.

The link guard (:mod:`companion.vehicle.link_guard`) relays every datagram between MAVSDK and
the autopilot; with a key it passes each one through a :class:`LinkSigner`:

- **Out** (MAVSDK -> autopilot): every frame is re-emitted signed, as the MAVLink signing
  specification builds it: the header's signed flag, the CRC computed again over the new header,
  then the 13-byte signature block (link id, a 48-bit timestamp in 10 us since 2015-01-01 that
  only ever grows, and the first 6 bytes of SHA-256(key + frame + link id + timestamp)). A
  MAVLink 1 frame is upgraded to MAVLink 2 first (MAVLink 1 has no room for a signature). A
  frame whose CRC is wrong, or whose message the codec does not know (its CRC seed unknown),
  cannot be signed: it is left out and counted.
- **In** (autopilot -> MAVSDK): a frame passes when its signature is the key's and its
  timestamp is newer than the last one of its (link, system, component) stream
  (:class:`uav_model.signing_key.SignatureCheck`, the stub's check too). RADIO_STATUS alone may come
  unsigned: a telemetry radio's own report, as the signing guide allows. An unsigned HEARTBEAT
  is refused, unlike on the stub, because MAVSDK reads the flight mode from it: a forged one
  would read as a mode change. Frames that pass are relayed as they came, signature and all.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink
from pymavlink.generator.mavcrc import x25crc

from companion.vehicle.link_probe import MAVLINK_IFLAG_SIGNED, MAVLINK_V1, MAVLINK_V2, frame_spans
from uav_model.signing_key import SIGNATURE_BYTES, SignatureCheck, signature, signing_timestamp

UNSIGNED_IN = frozenset({mavlink.MAVLINK_MSG_ID_RADIO_STATUS})
V2_HEADER_BYTES = 10
V1_HEADER_BYTES = 6
CRC_BYTES = 2


@dataclass(frozen=True)
class Refusal:
    """An incoming frame that did not pass: its sender and whether it carried a signature."""

    system_id: int
    msg_id: int
    signed: bool


def _crc(body: bytes | bytearray, msg_id: int) -> int | None:
    """The frame CRC of ``body`` (the header without its start byte, then the payload), or None
    when the codec does not know the message."""
    kind = mavlink.mavlink_map.get(msg_id)
    if kind is None:
        return None
    crc = x25crc(bytes(body))
    crc.accumulate(bytes((kind.crc_extra,)))
    return int(crc.crc)


class LinkSigner:
    """Signs what MAVSDK sends and checks what the autopilot sends; see the module docstring.
    Used by one relay thread only."""

    def __init__(self, key: bytes, link_id: int = 0):
        self._key = key
        self._link_id = link_id
        self._timestamp = signing_timestamp()
        self._check = SignatureCheck(key)
        self.signed = 0  # frames signed on their way out
        self.upgraded = 0  # of them, MAVLink 1 frames re-emitted as MAVLink 2
        self.unsignable = 0  # frames left out: a bad CRC or a message the codec does not know
        self.verified = 0  # incoming frames with a good signature
        self.refused = 0  # incoming frames dropped: unsigned, another key, or replayed

    def sign(self, datagram: bytes) -> bytes:
        """``datagram`` with every frame signed (the ones that cannot be are left out)."""
        out = bytearray()
        for start, end in frame_spans(datagram):
            signed = self._sign_frame(datagram[start:end])
            if signed is None:
                self.unsignable += 1
            else:
                out += signed
                self.signed += 1
        return bytes(out)

    def _sign_frame(self, frame: bytes) -> bytes | None:
        if frame[0] == MAVLINK_V2:
            n = frame[1]
            if len(frame) != V2_HEADER_BYTES + n + CRC_BYTES + (SIGNATURE_BYTES if frame[2] & MAVLINK_IFLAG_SIGNED else 0):
                return None
            msg_id = frame[7] | frame[8] << 8 | frame[9] << 16
            header = bytearray(frame[:V2_HEADER_BYTES])
            payload = frame[V2_HEADER_BYTES:V2_HEADER_BYTES + n]
        elif frame[0] == MAVLINK_V1:
            n = frame[1]
            if len(frame) != V1_HEADER_BYTES + n + CRC_BYTES:
                return None
            msg_id = frame[5]
            payload = frame[V1_HEADER_BYTES:V1_HEADER_BYTES + n]
            header = bytearray((MAVLINK_V2, n, 0, 0, frame[2], frame[3], frame[4], msg_id, 0, 0))
        else:
            return None
        crc_at = len(frame) - CRC_BYTES - (SIGNATURE_BYTES if frame[0] == MAVLINK_V2 and frame[2] & MAVLINK_IFLAG_SIGNED
                                           else 0)
        if _crc(frame[1:crc_at], msg_id) != int.from_bytes(frame[crc_at:crc_at + CRC_BYTES], "little"):
            return None  # corrupt, or unknown to the codec: a valid CRC must not be made up for it
        header[2] |= MAVLINK_IFLAG_SIGNED
        body = header + payload
        body += struct.pack("<H", _crc(body[1:], msg_id))
        self._timestamp = max(self._timestamp + 1, signing_timestamp())
        body += struct.pack("<BQ", self._link_id, self._timestamp)[:7]
        body += signature(self._key, body)
        if frame[0] == MAVLINK_V1:
            self.upgraded += 1
        return bytes(body)

    def check(self, datagram: bytes) -> tuple[bytes, set[int], list[Refusal]]:
        """The frames of ``datagram`` that pass, the system ids that signed them, and the refused."""
        passed = bytearray()
        signers: set[int] = set()
        refused: list[Refusal] = []
        for start, end in frame_spans(datagram):
            frame = datagram[start:end]
            v2 = frame[0] == MAVLINK_V2
            system_id = frame[5] if v2 else frame[3]
            msg_id = (frame[7] | frame[8] << 8 | frame[9] << 16) if v2 else (frame[5] if len(frame) > 5 else -1)
            signed = v2 and bool(frame[2] & MAVLINK_IFLAG_SIGNED)
            whole = end <= len(datagram)
            if signed and whole and self._check.verify(frame, system_id, frame[6]):
                self.verified += 1
                signers.add(system_id)
                passed += frame
            elif not signed and whole and msg_id in UNSIGNED_IN:
                passed += frame
            else:
                self.refused += 1
                refused.append(Refusal(system_id, msg_id, signed))
        return bytes(passed), signers, refused
