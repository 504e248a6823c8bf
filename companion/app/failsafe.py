"""Is a mode change the autopilot's offboard-loss failsafe, or an operator taking over? Pure: no I/O.

PX4 (../shared/px4-sih/README.md) meets late offboard setpoints with "Failsafe activated" and
then RTL (COM_OBL_RC_ACT 0, its default without RC) or Hold (5); it re-enters OFFBOARD by itself
once setpoints flow again. An operator's switch (to Hold, RTL or anything else) comes without
that notice, and PX4 does not leave it by itself. The evidence for a failsafe, any of:

- a failsafe STATUSTEXT heard recently (within :data:`NOTICE_WINDOW_SIM_S` of the vehicle's
  clock) and not yet used for an earlier recovery. The text comes first and the mode only at the
  next 1 Hz heartbeat, 1.1-2 s later on PX4, so position samples still in OFFBOARD come between;
- our own telemetry gap just before (the companion saw the link fail);
- the vehicle is already back in OFFBOARD without being asked (only PX4's failsafe does that).

MAVSDK delivers texts and modes on separate streams, so the text may also come a little after
the mode: a Hold or RTL without evidence is given a grace before it counts as an operator's. The
grace is seconds of wall time, not a moment: when the uplink is cut, PX4 stops hearing our
heartbeats and its "Failsafe activated" never reaches us, while the telemetry still does (no
gap either). The only evidence is then PX4 itself re-entering OFFBOARD once the setpoints,
streamed all through the grace, reach it again (measured: 0.2-3 s after they resume).

A geofence breach is told apart first: PX4 says "Geofence: approaching or outside geofence" (older
PX4 and the stub "Geofence violation: ...") as it takes GF_ACTION (Hold by default, then "Failsafe
activated" too). Any such notice heard in flight is a breach, in
whatever mode (with GF_ACTION 1 the vehicle stays in OFFBOARD): the flight ends with the failure
reason ``geofence``, and the companion does not fight the autopilot's action. The words are not
needed: a mode change out of OFFBOARD while the vehicle is at the fence it uploaded (``at_fence``,
from its own position) is the fence's action too. PX4 sends no FENCE_STATUS, and its STATUSTEXT
("Geofence: ...") may be lost on the link or split.

Every failsafe judged is kept as a :class:`FailsafeEvent` (the run's summary lists them).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from companion.vehicle.port import FlightMode, VehicleStatus

RECOVERABLE_MODES = frozenset({FlightMode.HOLD, FlightMode.RETURN_TO_LAUNCH})
NOTICE_WINDOW_SIM_S = 10.0  # a failsafe text this old (vehicle clock) still explains a Hold/RTL
OVERRIDE_GRACE_SIM_S = 2.0  # Hold/RTL without evidence: wait this long for a late text ...
OVERRIDE_GRACE_MIN_WALL_S = 6.0  # ... and at least this long in wall time: a cut uplink (~3 s) and PX4's re-entry


class FailsafeCause(enum.Enum):
    GEOFENCE = "geofence"  # a geofence breach notice: the fence was breached
    OFFBOARD_LOSS = "offboard_loss"  # setpoints were late (a failsafe notice or our own telemetry gap)


@dataclass(frozen=True, slots=True)
class FailsafeEvent:
    """One failsafe the autopilot took: when (its clock, and mission time once departed), the mode
    it entered, why, and whether OFFBOARD came back."""

    vehicle: str
    t_sim_s: float | None
    t_mission_s: float | None
    mode: str
    cause: FailsafeCause
    recovered: bool
    notice: str | None = None  # the autopilot's words, when it said any

    def summary_dict(self) -> dict[str, object]:
        r = (lambda v: None if v is None else round(v, 3))
        return {"vehicle": self.vehicle, "t_sim_s": r(self.t_sim_s), "t_mission_s": r(self.t_mission_s),
                "mode": self.mode, "cause": self.cause.value, "recovered": self.recovered, "notice": self.notice}


class ModeVerdict(enum.Enum):
    FLYING = "flying"  # OFFBOARD, nothing happened
    FENCE = "fence"  # the autopilot reported a geofence breach: the flight has failed
    RESUMED = "resumed"  # back in OFFBOARD by itself after a failsafe we may not even have seen
    RECOVER = "recover"  # a failsafe: keep streaming and resume OFFBOARD
    WAIT = "wait"  # Hold/RTL without evidence yet: the failsafe text may still come
    OVERRIDE = "override"  # someone else chose this mode: stand down


class FailsafeWatch:
    """Judges each mode the pilot sees; remembers which failsafe notices it has already used."""

    def __init__(self, status: VehicleStatus):
        self.mode_changes = status.mode_changes
        self.used_notice_t: float | None = status.last_failsafe_t_sim_s  # notices before OFFBOARD do not count
        self.fence_notices = status.fence_notices  # likewise for breach notices
        self.fence_where: str | None = None  # at_fence, when that (not a notice) made the verdict FENCE
        self.recovering = False  # a failsafe is being recovered: until OFFBOARD is back, Hold/RTL stay one
        self.grace_since_wall: float | None = None

    def _fresh_notice(self, st: VehicleStatus, clock_s: float | None) -> bool:
        t = st.last_failsafe_t_sim_s
        if t is None or (self.used_notice_t is not None and t <= self.used_notice_t):
            return False
        return clock_s is None or clock_s - t <= NOTICE_WINDOW_SIM_S

    def _use_notice(self, st: VehicleStatus) -> None:
        if st.last_failsafe_t_sim_s is not None:
            self.used_notice_t = st.last_failsafe_t_sim_s

    def judge(self, st: VehicleStatus, clock_s: float | None, now_wall_s: float, grace_wall_s: float,
              recent_gap: bool, at_fence: str | None = None) -> ModeVerdict:
        """``at_fence``: where the vehicle is at its uploaded fence (``fence.FenceGeometry.breach``), or None."""
        if st.fence_notices != self.fence_notices or (at_fence is not None and st.mode is not FlightMode.OFFBOARD):
            self.fence_where = at_fence if st.fence_notices == self.fence_notices else None
            self.fence_notices = st.fence_notices
            self._use_notice(st)  # its "Failsafe activated" is the fence's, not an offboard loss
            return ModeVerdict.FENCE
        if st.mode is FlightMode.OFFBOARD:
            changed = st.mode_changes != self.mode_changes
            self.mode_changes = st.mode_changes
            self.grace_since_wall = None
            was_recovering, self.recovering = self.recovering, False
            if changed and st.last_other_mode in RECOVERABLE_MODES and not was_recovering:
                self._use_notice(st)
                return ModeVerdict.RESUMED
            return ModeVerdict.FLYING
        if st.mode not in RECOVERABLE_MODES:
            return ModeVerdict.OVERRIDE
        if self.recovering or recent_gap or self._fresh_notice(st, clock_s):
            self._use_notice(st)
            self.recovering = True
            self.grace_since_wall = None
            return ModeVerdict.RECOVER
        if self.grace_since_wall is None:
            self.grace_since_wall = now_wall_s
        return ModeVerdict.WAIT if now_wall_s - self.grace_since_wall < grace_wall_s else ModeVerdict.OVERRIDE

    def offboard_confirmed(self, st: VehicleStatus) -> None:
        """We saw OFFBOARD come back after asking for it (or waiting for it): nothing to count twice."""
        self.mode_changes = st.mode_changes
        self.recovering = False
        self.grace_since_wall = None
        self._use_notice(st)
