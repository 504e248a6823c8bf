"""The sim clock: sim time runs at ``speedup`` times the wall clock, in fixed physics steps. Pure.

The I/O layer asks how many steps are due at a wall time and runs them. If the process falls
behind by more than ``max_lag_steps`` (a stalled event loop, a slow machine), the clock slips
instead of bursting through the backlog: the achieved speed factor drops and says so.
"""

from __future__ import annotations

import math


class ClockError(ValueError):
    """An unusable speed factor or step."""


class SimClock:
    def __init__(self, speedup: float, dt_s: float, wall_start_s: float, max_lag_steps: int = 50):
        if not (math.isfinite(speedup) and 0.01 <= speedup <= 1000.0):
            raise ClockError(f"speedup {speedup}: must be in [0.01, 1000]")
        if not (math.isfinite(dt_s) and 0.001 <= dt_s <= 0.5):
            raise ClockError(f"physics step {dt_s} s: must be in [0.001, 0.5]")
        self.speedup = speedup
        self.dt_s = dt_s
        self._wall_origin = wall_start_s  # wall time at which sim time was 0 (moves on a slip)
        self._wall_start = wall_start_s
        self._steps = 0
        self._max_lag = max_lag_steps
        self.slipped_s = 0.0  # sim seconds given up to slips

    @property
    def sim_time_s(self) -> float:
        return self._steps * self.dt_s

    @property
    def steps(self) -> int:
        return self._steps

    def steps_due(self, wall_t: float) -> int:
        """Steps to run now to catch sim time up with the wall clock (at most max_lag_steps)."""
        target = (wall_t - self._wall_origin) * self.speedup
        due = int(math.floor((target - self.sim_time_s) / self.dt_s + 1e-9))
        if due > self._max_lag:
            behind_s = (due - self._max_lag) * self.dt_s
            self._wall_origin += behind_s / self.speedup
            self.slipped_s += behind_s
            due = self._max_lag
        return max(0, due)

    def advance(self) -> float:
        """Count one physics step as done; returns the new sim time."""
        self._steps += 1
        return self.sim_time_s

    def wall_of_next_step(self) -> float:
        return self._wall_origin + (self.sim_time_s + self.dt_s) / self.speedup

    def achieved_speedup(self, wall_t: float) -> float:
        elapsed = wall_t - self._wall_start
        return self.sim_time_s / elapsed if elapsed > 0 else 0.0
