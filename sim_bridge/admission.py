"""Whom the stub obeys: an allowlist of sender system ids, and MAVLink 2 signing.

Without either, the stub does what PX4 does without signing: it takes arm, take-off, OFFBOARD
and disarm from anyone who can reach its sockets. With ``allow_sysids``, a message from any
other system id is dropped before a vehicle sees it. With a signing key, every frame the stub
sends is signed, and a frame that is unsigned or signed with another key is dropped (HEARTBEAT
and RADIO_STATUS excepted, as the MAVLink signing guide allows). Each refusal is counted and
logged once per (socket, sender, message type); it has no effect on the vehicle.

Key files (``--signing-key FILE``) are read by :func:`uav_model.signing_key.load_signing_key`,
the one loader the companion uses too.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from uav_model.signing_key import SignatureCheck, signing_timestamp

log = logging.getLogger(__name__)

UNSIGNED_OK = frozenset({mavlink.MAVLINK_MSG_ID_HEARTBEAT, mavlink.MAVLINK_MSG_ID_RADIO_STATUS})
INVALID_SIGNATURE = "Invalid signature"  # pymavlink's reason on a refused frame
MAX_LOGGED = 256  # distinct (socket, sender, type) refusals logged; a flood of senders is only counted


def parse_sysids(text: str) -> frozenset[int]:
    """``255,245`` -> {255, 245}; ValueError naming the bad item."""
    out = set()
    for item in text.split(","):
        item = item.strip()
        if not item.isdigit() or not 1 <= int(item) <= 255:
            raise ValueError(f"--allow-sysid {text!r}: {item!r} is not a system id (1..255)")
        out.add(int(item))
    return frozenset(out)


@dataclass
class Admission:
    """The stub's gate for incoming messages; see the module docstring."""

    allow_sysids: frozenset[int] | None = None
    signing_key: bytes | None = None

    def __post_init__(self) -> None:
        self.refused = 0
        self._logged: set[tuple[str, Any, int, str]] = set()

    def sign(self, encoder: Any, link_id: int) -> Any:
        """``encoder`` (a pymavlink MAVLink), made to sign what it packs when there is a key."""
        if self.signing_key is None:
            return encoder
        encoder.signing.secret_key = self.signing_key
        encoder.signing.link_id = link_id
        encoder.signing.timestamp = signing_timestamp()
        encoder.signing.sign_outgoing = True
        return encoder

    def stamp(self, encoder: Any) -> Any:
        """Before packing: the signing timestamp follows the clock (pymavlink only adds one per frame),
        so a peer that joins later does not see a stream from the past."""
        if self.signing_key is not None:
            encoder.signing.timestamp = max(encoder.signing.timestamp, signing_timestamp())
        return encoder

    def check_signatures(self, parser: Any) -> None:
        """Make a per-peer parser refuse unsigned or badly signed frames, when there is a key."""
        if self.signing_key is None:
            return
        parser.signing.secret_key = self.signing_key
        parser.signing.timestamp = signing_timestamp()
        parser.signing.allow_unsigned_callback = lambda _mav, msg_id: msg_id in UNSIGNED_OK
        # pymavlink's own check moves a stream's timestamp before it checks the signature.
        parser.check_signature = SignatureCheck(self.signing_key).verify

    def refusal(self, msg: Any) -> str | None:
        """Why a decoded message must not reach a vehicle, or None."""
        if self.allow_sysids is not None and msg.get_srcSystem() not in self.allow_sysids:
            allowed = ",".join(str(s) for s in sorted(self.allow_sysids))
            return f"system id {msg.get_srcSystem()} is not in --allow-sysid {allowed}"
        return None

    def admits(self, msg: Any, datagram: bytes, socket_name: str, peer: Any) -> bool:
        """False (counted, logged once) when ``msg`` must not reach a vehicle: a frame pymavlink
        refused for its signature, or a sender outside the allowlist. Other garbage is admitted
        here: it is the caller's to count."""
        if msg.get_type() == "BAD_DATA":
            if INVALID_SIGNATURE not in getattr(msg, "reason", ""):
                return True
            sysid = datagram[5] if len(datagram) >= 10 and datagram[0] == 0xFD else 0
            self.note_refused(socket_name, peer, sysid, "a frame", "unsigned or not signed with --signing-key")
            return False
        why = self.refusal(msg)
        if why is not None:
            self.note_refused(socket_name, peer, msg.get_srcSystem(), msg.get_type(), why)
        return why is None

    def note_refused(self, socket_name: str, peer: Any, sysid: int, what: str, why: str) -> None:
        self.refused += 1
        key = (socket_name, peer, sysid, what)
        if key not in self._logged and len(self._logged) < MAX_LOGGED:
            self._logged.add(key)
            log.warning("refused %s from system %d at %s on the %s link: %s (further ones counted, not logged)",
                        what, sysid, peer, socket_name, why)
