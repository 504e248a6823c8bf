"""STATUSTEXT as PX4 sends it: a tab after event texts, long texts split into 50-byte chunks. Pure.

PX4 reports most of its messages through its events interface and mirrors each as a STATUSTEXT
with a tab appended ("Armed by external command\t"), so a ground station that also gets the
event can tell the copy; the health-check texts ("Preflight Fail: ...") are plain. A text longer
than the 50-byte field goes out as several STATUSTEXT chunks sharing a non-zero ``id`` with
``chunk_seq`` 0, 1, ... (MAVLink's long-statustext rule): measured on PX4 SIH, "Arming denied:
Resolve system health failures first" arrives as "... failures firs" then "t\\t".
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

CHUNK_BYTES = 50
EVENT_SUFFIX = "\t"
PLAIN_PREFIXES = ("Preflight Fail:",)  # PX4 health reports: no events mirror, no tab


def px4_text(text: str) -> str:
    """The text PX4 would put on the wire for a message the stub says."""
    return text if text.startswith(PLAIN_PREFIXES) or text.endswith(EVENT_SUFFIX) else text + EVENT_SUFFIX


def chunks(text: str) -> list[bytes]:
    """``text`` (already in PX4's form) as the 50-byte pieces of one logical STATUSTEXT."""
    raw = text.encode("ascii", "replace")
    return [raw[i:i + CHUNK_BYTES] for i in range(0, max(len(raw), 1), CHUNK_BYTES)]


def _text_of(msg: Any) -> str:
    text = msg.text
    return (text.decode("ascii", "replace") if isinstance(text, (bytes, bytearray)) else str(text)).rstrip("\x00")


class StatustextSplitter:
    """Rewrites the STATUSTEXTs among a vehicle's outgoing messages into PX4's wire form."""

    def __init__(self, codec: Any):
        self._mav = codec  # a pymavlink MAVLink used as the message factory
        self._next_id = 0

    def _new_id(self) -> int:
        self._next_id = self._next_id % 65535 + 1  # 0 means "single chunk"
        return self._next_id

    def expand(self, emits: Iterable[Any]) -> list[Any]:
        """``emits`` (NamedTuples with a ``msg``, as the vehicle's Emit) with each STATUSTEXT in wire form."""
        out: list[Any] = []
        for e in emits:
            msg = e.msg
            if msg.get_msgId() != mavlink.MAVLINK_MSG_ID_STATUSTEXT:
                out.append(e)
                continue
            pieces = chunks(px4_text(_text_of(msg)))
            msg_id = self._new_id() if len(pieces) > 1 else 0
            for seq, piece in enumerate(pieces):
                out.append(e._replace(msg=self._mav.statustext_encode(msg.severity, piece, msg_id, seq)))
        return out
