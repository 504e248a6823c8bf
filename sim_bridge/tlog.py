"""``.tlog`` recording of the GCS stream, in the format pymavlink and QGroundControl read.

Each record is an 8-byte big-endian timestamp (microseconds since the Unix epoch, wall clock)
followed by one raw MAVLink frame. Records are buffered and flushed at least once a second of
wall time, so a crash loses at most the last second (SPEC section 6).
"""

from __future__ import annotations

import re
import struct
import time
from pathlib import Path
from typing import BinaryIO

FLUSH_INTERVAL_S = 1.0


class TlogWriter:
    def __init__(self, path: Path, stream: BinaryIO):
        self.path = path
        self._f = stream
        self._last_flush = 0.0
        self.records = 0

    @classmethod
    def create(cls, directory: Path, name: str) -> "TlogWriter":
        directory.mkdir(parents=True, exist_ok=True)
        safe = re.sub(r"[^A-Za-z0-9_.-]", "_", name) or "sim"
        stamp = time.strftime("%Y%m%d-%H%M%S")
        path = directory / f"{safe}-{stamp}.tlog"
        n = 1
        while path.exists():
            path = directory / f"{safe}-{stamp}-{n}.tlog"
            n += 1
        return cls(path, open(path, "xb"))  # noqa: SIM115 - closed in close()

    def write(self, frame: bytes) -> None:
        if self._f.closed:
            return
        self._f.write(struct.pack(">Q", int(time.time() * 1e6)) + bytes(frame))
        self.records += 1

    def maybe_flush(self, wall_t: float) -> None:
        if wall_t - self._last_flush >= FLUSH_INTERVAL_S and not self._f.closed:
            self._f.flush()
            self._last_flush = wall_t

    def close(self) -> None:
        if not self._f.closed:
            self._f.close()
