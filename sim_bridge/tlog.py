"""``.tlog`` recording of the GCS stream, in the format pymavlink and QGroundControl read.

Each record is an 8-byte big-endian timestamp (microseconds since the Unix epoch) followed by one
raw MAVLink frame. The timestamp is **sim time** (the wall clock at the sim's start plus the sim
seconds elapsed), so at 20x mavlogdump and mavflightmodes report the flight as flown: a 478 s
flight, not the 24 s of wall time it took. Records are buffered and flushed at least once a
second of wall time, so a crash loses at most the last second (SPEC section 6). A write the disk
refuses stops that file with one ``tlog error:`` log line naming it, the reason and how many
records it kept (``TlogWriter.error``); the sim flies on.

:class:`TlogSet` writes the combined log and, on request, one log per vehicle (the frames a
vehicle sent, and those addressed to it or to everyone).
"""

from __future__ import annotations

import logging
import re
import struct
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import BinaryIO

FLUSH_INTERVAL_S = 1.0
log = logging.getLogger(__name__)


class TlogWriter:
    def __init__(self, path: Path, stream: BinaryIO, clock_s: Callable[[], float] = time.time):
        self.path = path
        self._f = stream
        self._clock_s = clock_s
        self._last_flush = 0.0
        self.records = 0
        self.flushed_records = 0  # on disk for sure: the file ends here if a later write fails
        self.error: str | None = None

    @classmethod
    def create(cls, directory: Path, name: str, clock_s: Callable[[], float] = time.time) -> "TlogWriter":
        directory.mkdir(parents=True, exist_ok=True)
        safe = re.sub(r"[^A-Za-z0-9_.-]", "_", name) or "sim"
        stamp = time.strftime("%Y%m%d-%H%M%S")
        path = directory / f"{safe}-{stamp}.tlog"
        n = 1
        while path.exists():
            path = directory / f"{safe}-{stamp}-{n}.tlog"
            n += 1
        return cls(path, open(path, "xb"), clock_s)  # noqa: SIM115 - closed in close()

    def write(self, frame: bytes) -> None:
        if self._f.closed:
            return
        try:
            self._f.write(struct.pack(">Q", int(self._clock_s() * 1e6)) + bytes(frame))
        except OSError as exc:
            self._fail(exc)
            return
        self.records += 1

    def maybe_flush(self, wall_t: float) -> None:
        if wall_t - self._last_flush >= FLUSH_INTERVAL_S and not self._f.closed:
            self._flush()
            self._last_flush = wall_t

    def _flush(self) -> None:
        try:
            self._f.flush()
        except OSError as exc:
            self._fail(exc)
            return
        self.flushed_records = self.records

    def _fail(self, exc: OSError) -> None:
        self.error = exc.strerror or str(exc)
        log.error("tlog error: %s truncated: %s; recording stopped after %d of %d records",
                  self.path.name, self.error, self.flushed_records, self.records + 1)
        try:
            self._f.close()
        except OSError:
            pass  # the buffered records cannot be written either

    def close(self) -> None:
        if not self._f.closed:
            self._flush()
            if not self._f.closed:
                try:
                    self._f.close()
                except OSError as exc:
                    self._fail(exc)


class TlogSet:
    """The combined GCS-stream log, plus one per vehicle when asked, all stamped by one clock."""

    def __init__(self, directory: Path, name: str, vehicles: Iterable[tuple[int, str]],
                 clock_s: Callable[[], float], per_vehicle: bool = False):
        self.combined = TlogWriter.create(directory, name, clock_s)
        self.by_system: dict[int, TlogWriter] = {}
        if per_vehicle:
            for system_id, vehicle in vehicles:
                self.by_system[system_id] = TlogWriter.create(directory, f"{name}-{vehicle}", clock_s)

    @property
    def paths(self) -> list[Path]:
        return [self.combined.path] + [w.path for w in self.by_system.values()]

    def write(self, frame: bytes, system_id: int | None) -> None:
        """Record a frame; ``system_id`` is the vehicle it belongs to, or None for every vehicle."""
        self.combined.write(frame)
        if system_id is None:
            for w in self.by_system.values():
                w.write(frame)
        elif system_id in self.by_system:
            self.by_system[system_id].write(frame)

    def maybe_flush(self, wall_t: float) -> None:
        for w in (self.combined, *self.by_system.values()):
            w.maybe_flush(wall_t)

    def close(self) -> None:
        for w in (self.combined, *self.by_system.values()):
            w.close()
