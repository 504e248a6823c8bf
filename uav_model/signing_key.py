"""MAVLink 2 signing's shared secret and clock, for the stub and the companion alike.

Key files (``--signing-key FILE``, on ``sim-bridge`` and ``companion run``): exactly 32 bytes are
the key; otherwise the text, stripped, is 64 hex digits (the key) or a passphrase whose SHA-256
is the key (MAVProxy's ``signing setup PASSPHRASE`` rule), so the same passphrase signs in
MAVProxy, the stub and the companion.

Signing timestamps count 10 microseconds since 1 January 2015 00:00 UTC (the MAVLink signing
specification), in 48 bits on the wire. :class:`SignatureCheck` is the one check of an incoming
signed frame: the signature first, then the timestamp against its stream's last.
"""

from __future__ import annotations

import hashlib
import re
import time
from pathlib import Path

KEY_BYTES = 32
MAX_KEY_FILE_BYTES = 4096
SIGNING_EPOCH_UNIX_S = 1420070400  # 1 January 2015 00:00 UTC: signing timestamps count from here
SIGNATURE_BYTES = 13  # link id (1), timestamp (6), signature (6)
NEW_STREAM_SLACK = 60 * 100_000  # a new stream's first timestamp may be a minute behind the clock (signing units)


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


def signature(key: bytes, signed_part: bytes | bytearray) -> bytes:
    """The 6 signature bytes of a frame: ``signed_part`` is the frame from its start byte to the
    signature's timestamp (header, payload, CRC, link id, timestamp)."""
    return hashlib.sha256(key + bytes(signed_part)).digest()[:6]


class SignatureCheck:
    """Checks signed MAVLink 2 frames from one peer against ``key``: the signature (the first 6
    bytes of SHA-256(key + frame up to the signature)) must match, then the timestamp must be
    newer than the last one of its (link id, system, component) stream (a replay is refused)
    and, for a new stream, at most a minute behind the clock. The signature is checked first:
    pymavlink moves the stream's timestamp before it checks, so one forged frame with a
    far-future timestamp would lock the real sender out."""

    def __init__(self, key: bytes):
        self._key = key
        self._streams: dict[tuple[int, int, int], int] = {}

    def verify(self, frame: bytes | bytearray, system_id: int, component_id: int) -> bool:
        """True for a whole signed frame (header to signature) that passes; see the class docstring."""
        if signature(self._key, frame[:-6]) != bytes(frame[-6:]):
            return False
        link_id, timestamp = frame[-SIGNATURE_BYTES], int.from_bytes(frame[-12:-6], "little")
        stream = (link_id, system_id, component_id)
        last = self._streams.get(stream)
        if last is None:
            if timestamp + NEW_STREAM_SLACK < signing_timestamp():
                return False
        elif timestamp <= last:
            return False
        self._streams[stream] = timestamp
        return True
