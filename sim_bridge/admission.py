"""Whom the stub obeys: an allowlist of sender system ids, and MAVLink 2 signing.

Without either, the stub does what PX4 does without signing: it takes arm, take-off, OFFBOARD
and disarm from anyone who can reach its sockets. With ``allow_sysids``, a message from any
other system id is dropped before a vehicle sees it. With a signing key, every frame the stub
sends is signed, and a frame that is unsigned or signed with another key is dropped (HEARTBEAT
and RADIO_STATUS excepted, as the MAVLink signing guide allows). Each refusal is counted and
logged once per (socket, sender, message type); it has no effect on the vehicle.

Key files (``--signing-key FILE``): exactly 32 bytes are the key; otherwise the text, stripped,
is 64 hex digits (the key) or a passphrase whose SHA-256 is the key (MAVProxy's ``signing
setup PASSPHRASE`` rule), so the same passphrase signs in MAVProxy and here.
"""

from __future__ import annotations

import hashlib
import logging
import re
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

log = logging.getLogger(__name__)

KEY_BYTES = 32
MAX_KEY_FILE_BYTES = 4096
UNSIGNED_OK = frozenset({mavlink.MAVLINK_MSG_ID_HEARTBEAT, mavlink.MAVLINK_MSG_ID_RADIO_STATUS})
SIGNING_EPOCH_UNIX_S = 1420070400  # 1 January 2015 00:00 UTC: signing timestamps count from here
INVALID_SIGNATURE = "Invalid signature"
MAX_LOGGED = 256  # distinct (socket, sender, type) refusals logged; a flood of senders is only counted  # pymavlink's reason on a refused frame


class SigningKeyError(ValueError):
    """The key file cannot be used; one line naming the file."""


def load_signing_key(path: Path) -> bytes:
    """The 32-byte secret from a key file (see the module docstring for the formats)."""
    try:
        if not path.is_file():
            raise SigningKeyError(f"--signing-key {path}: not a regular file")
        with open(path, "rb") as f:
            data = f.read(MAX_KEY_FILE_BYTES + 1)
    except OSError as exc:
        raise SigningKeyError(f"--signing-key {path}: cannot read it ({exc.strerror})") from None
    if len(data) > MAX_KEY_FILE_BYTES:
        raise SigningKeyError(f"--signing-key {path}: larger than {MAX_KEY_FILE_BYTES} bytes; "
                              "expected a 32-byte key, 64 hex digits or a passphrase")
    if len(data) == KEY_BYTES:
        return data
    try:
        text = data.decode("utf-8").strip()
    except UnicodeDecodeError:
        raise SigningKeyError(f"--signing-key {path}: {len(data)} bytes of binary; a raw key is exactly "
                              f"{KEY_BYTES} bytes") from None
    if not text:
        raise SigningKeyError(f"--signing-key {path}: empty")
    if re.fullmatch(r"[0-9a-fA-F]{64}", text):
        return bytes.fromhex(text)
    return hashlib.sha256(text.encode("utf-8")).digest()


def signing_timestamp(unix_s: float | None = None) -> int:
    """Now in signing units (10 microseconds since 2015-01-01 UTC)."""
    return int(((time.time() if unix_s is None else unix_s) - SIGNING_EPOCH_UNIX_S) * 100_000)


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

    def check_signatures(self, parser: Any) -> None:
        """Make a per-peer parser refuse unsigned or badly signed frames, when there is a key."""
        if self.signing_key is None:
            return
        parser.signing.secret_key = self.signing_key
        parser.signing.timestamp = signing_timestamp()
        parser.signing.allow_unsigned_callback = lambda _mav, msg_id: msg_id in UNSIGNED_OK

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
