"""Flight logs written as the flight goes: flight.csv (one row per planner tick and event) and
traffic.csv (every ADS-B report of a moving obstacle that reached the companion).

Rows are flushed to the OS at least every ``flush_every_s`` of wall time, so that a crash of the
companion loses at most that much. The per-vehicle tracks that the shared metrics module needs
are kept in memory alongside. A write error (a full disk) never reaches the flight: that file
stops there and :meth:`FlightLog.problems` names it, as it names a file whose folder was removed.
"""

from __future__ import annotations

import csv
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

FLIGHT_COLUMNS = (
    "t_mission_s", "t_sim_s", "vehicle", "phase", "mode", "x_m", "y_m", "alt_m", "heading_deg",
    "speed_m_s", "cmd_forward_m_s", "cmd_yaw_rate_deg_s", "action", "goal_index", "dist_to_goal_m",
    "clearance_m", "separation_m", "planner_ms", "t_plan_s", "note",
)
TRAFFIC_COLUMNS = ("t_sim_s", "callsign", "via", "x_m", "y_m", "vx_m_s", "vy_m_s")


@dataclass
class Track:
    """One vehicle's flown path in mission time (seconds since its departure) and ENU metres."""

    t_s: list[float] = field(default_factory=list)
    x_m: list[float] = field(default_factory=list)
    y_m: list[float] = field(default_factory=list)

    def add(self, t_s: float, x_m: float, y_m: float) -> None:
        if self.t_s and t_s <= self.t_s[-1]:
            return  # a repeated or reordered sample adds nothing to a track
        self.t_s.append(t_s)
        self.x_m.append(x_m)
        self.y_m.append(y_m)

    def __len__(self) -> int:
        return len(self.t_s)


def _fmt(value) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return "" if not math.isfinite(value) else f"{value:.3f}"
    return str(value)


class FlightLog:
    """CSV writers plus in-memory tracks. Use as a context manager; ``None`` directory: tracks only."""

    def __init__(self, out_dir: Path | None, *, flush_every_s: float = 0.5):
        self.out_dir = out_dir
        self.flush_every_s = flush_every_s
        self.tracks: dict[str, Track] = {}
        self.traffic_rows = 0
        self._files: list[IO[str]] = []
        self._failed: dict[str, str] = {}  # file name -> why it stopped
        self._rows: dict[str, int] = {"flight.csv": 0, "traffic.csv": 0}
        self._flight: csv.writer | None = None
        self._traffic: csv.writer | None = None
        self._last_flush = time.monotonic()
        self._last_traffic: dict[tuple[str, str], float] = {}

    def __enter__(self) -> "FlightLog":
        if self.out_dir is not None:
            self.out_dir.mkdir(parents=True, exist_ok=True)
            f = open(self.out_dir / "flight.csv", "w", newline="", encoding="utf-8")
            t = open(self.out_dir / "traffic.csv", "w", newline="", encoding="utf-8")
            self._files = [f, t]
            self._flight = csv.writer(f)
            self._traffic = csv.writer(t)
            self._flight.writerow(FLIGHT_COLUMNS)
            self._traffic.writerow(TRAFFIC_COLUMNS)
            self.flush()
        return self

    def __exit__(self, *exc) -> None:
        self.flush()
        for f in self._files:
            self._close(f)
        self._files = []

    def problems(self) -> list[str]:
        """One line per log file that is not complete on disk: stopped by a write error, or
        written into a folder that was removed in flight (the file has no name left)."""
        out = [f"{name} ({why}; stopped after {self._rows[name]} rows)" for name, why in self._failed.items()]
        for f in self._files:
            name = Path(f.name).name
            try:
                if name not in self._failed and os.fstat(f.fileno()).st_nlink == 0:
                    out.append(f"{name} (deleted with its folder during the run)")
            except (OSError, ValueError):
                pass
        return out

    def _close(self, f: IO[str]) -> None:
        try:
            f.close()
        except OSError as exc:
            self._stop(f, exc)

    def _stop(self, f: IO[str], exc: OSError) -> None:
        """A write to ``f`` failed: record why, drop its buffer and write no more to it."""
        name = Path(f.name).name
        self._failed.setdefault(name, exc.strerror or str(exc))
        if name == "flight.csv":
            self._flight = None
        else:
            self._traffic = None
        try:
            f.close()
        except OSError:
            pass  # the buffered rows cannot go anywhere: the file ends at the last good flush

    def track(self, vehicle: str) -> Track:
        return self.tracks.setdefault(vehicle, Track())

    def row(self, **values) -> None:
        unknown = set(values) - set(FLIGHT_COLUMNS)
        if unknown:
            raise ValueError(f"unknown flight.csv columns: {sorted(unknown)}")
        if self._flight is not None:
            self._write(self._files[0], self._flight, [_fmt(values.get(c)) for c in FLIGHT_COLUMNS])
        self._maybe_flush()

    def traffic(self, t_sim_s: float, callsign: str, via: str, x_m: float, y_m: float,
                vx_m_s: float, vy_m_s: float) -> None:
        key = (callsign, via)
        if self._last_traffic.get(key) == t_sim_s:
            return  # the same report seen again through the board
        self._last_traffic[key] = t_sim_s
        self.traffic_rows += 1
        if self._traffic is not None:
            self._write(self._files[1], self._traffic,
                        [_fmt(t_sim_s), callsign, via, _fmt(x_m), _fmt(y_m), _fmt(vx_m_s), _fmt(vy_m_s)])
        self._maybe_flush()

    def _write(self, f: IO[str], writer, row: list[str]) -> None:
        try:
            writer.writerow(row)
            self._rows[Path(f.name).name] += 1
        except OSError as exc:
            self._stop(f, exc)

    def _maybe_flush(self) -> None:
        if time.monotonic() - self._last_flush >= self.flush_every_s:
            self.flush()

    def flush(self) -> None:
        for f in self._files:
            if f.closed:
                continue
            try:
                f.flush()
            except OSError as exc:
                self._stop(f, exc)
        self._last_flush = time.monotonic()
