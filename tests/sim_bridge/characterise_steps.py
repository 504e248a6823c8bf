"""The steps of ``characterise.py``'s log, and how close the stub's must come to PX4's.

``characterise.py`` (../shared/px4-sih/) prints one line per event or result, ``[w WALL s SIM]
text``. A :class:`Step` pulls one value out of such a log (an ack, a mode, a parameter, a
duration) and says when the stub's value matches PX4's: exactly for acks, modes, texts and
parameters; within a stated tolerance for times and speeds. The tolerances are the ones in
docs/sim_bridge.md ("Step by step against PX4").
"""

from __future__ import annotations

import ast
import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

LINE = re.compile(r"^\[w\s*(?P<w>[\d.]+) s\s*(?P<s>[\d.]+)\] (?P<text>.*)$")

PARAMS = ("COM_OF_LOSS_T", "COM_OBL_RC_ACT", "COM_RCL_EXCEPT", "NAV_RCL_ACT", "NAV_DLL_ACT", "COM_RC_IN_MODE",
          "MIS_TAKEOFF_ALT", "MPC_XY_VEL_MAX", "MPC_ACC_HOR", "MPC_ACC_HOR_MAX", "MC_YAWRATE_MAX", "MPC_YAWRAUTO_MAX",
          "COM_DISARM_LAND", "COM_DISARM_PRFLT", "COM_FAIL_ACT_T", "MPC_TKO_SPEED", "NAV_ACC_RAD", "MPC_XY_CRUISE",
          "COM_DL_LOSS_T", "MPC_LAND_SPEED", "MAV_SYS_ID", "SIM_BAT_DRAIN", "SIM_BAT_MIN_PCT", "COM_SPOOLUP_TIME")


@dataclass(frozen=True)
class Line:
    sim_s: float
    text: str


def parse_log(text: str) -> list[Line]:
    out = []
    for raw in text.splitlines():
        m = LINE.match(raw)
        if m:
            out.append(Line(float(m["s"]), m["text"]))
    return out


# ---------------------------------------------------------------- extractors ---------------
def _after(log: list[Line], marker: str | None) -> list[Line]:
    if marker is None:
        return log
    for i, line in enumerate(log):
        if line.text.startswith(marker):
            return log[i + 1:]
    return []


def first(pattern: str, after: str | None = None, group: int | str = 1, convert: Callable[[str], Any] = str):
    """The first match of ``pattern`` (after the line starting with ``after``); None if absent."""
    rx = re.compile(pattern)

    def get(log: list[Line]) -> Any:
        for line in _after(log, after):
            m = rx.search(line.text)
            if m:
                return convert(m.group(group))
        return None
    return get


def sim_time_of(pattern: str, after: str | None = None):
    rx = re.compile(pattern)

    def get(log: list[Line]) -> float | None:
        return next((line.sim_s for line in _after(log, after) if rx.search(line.text)), None)
    return get


def has(text: str):
    return lambda log: any(line.text == text for line in log)


def landed_states(log: list[Line]) -> list[int]:
    return [int(m.group(1)) for line in log if (m := re.search(r"landed_state=(\d)", line.text))]


def statustext_split(log: list[Line]) -> bool:
    """PX4's long-text split: a 50-character chunk, then the rest with the tab."""
    texts = [line.text for line in log if line.text.startswith("STATUSTEXT")]
    return any(a.endswith("Resolve system health failures firs") and b.endswith(": t\t") for a, b in zip(texts, texts[1:]))


def auto_reentry_from_hold(log: list[Line]) -> bool:
    """OFFBOARD seen in a heartbeat after the Hold failsafe, well before the client asks for it.

    A heartbeat that answers the client's own DO_SET_MODE comes within a physics step or two of
    its ack (the script prints it first), so a re-entry counts only if it shows 0.05 s (sim) or more
    before the ack. The re-entry itself is at the first resumed setpoint; which 1 Hz heartbeat shows
    it depends on the phase, up to ~1 s later, and the client asks 1 s after resuming.
    """
    tail = _after(log, "STOP setpoints with COM_OBL_RC_ACT=5")
    ack_t = next((x.sim_s for x in tail if x.text.startswith("COMMAND_ACK re-enter OFFBOARD")), math.inf)
    return any(x.text.startswith("HEARTBEAT mode OFFBOARD") and x.sim_s <= ack_t - 0.05 for x in tail)


def failsafe_state(log: list[Line]) -> int | None:
    """HEARTBEAT system_status when the first offboard-loss failsafe shows."""
    for line in _after(log, "STOP setpoints (offboard loss)"):
        if line.text.startswith("HEARTBEAT mode"):
            return int(line.text.rsplit("state=", 1)[1])
    return None


def arming_window(log: list[Line]) -> tuple[float, float] | None:
    """(last refused try, accepted try), sim s: the boot refusal ended in between.

    The script retries every ~0.5 s, so when the first accepted try comes depends on where its
    tries fall; the window in which the refusal ended is what PX4 and the stub must share.
    """
    refused = [x.sim_s for x in log if re.match(r"^COMMAND_ACK ARM try \d+: MAV_RESULT_TEMPORARILY_REJECTED", x.text)]
    accepted = sim_time_of(r"^arm accepted after")(log)
    return None if accepted is None else (refused[-1] if refused else 0.0, accepted)


def same_window(tol: float):
    """Two (lower, upper] windows that overlap once widened by ``tol``."""
    return lambda a, b: a is not None and b is not None and a[0] - tol < b[1] and b[0] - tol < a[1]


def exchange(label: str):
    """Message types and sequence numbers of a mission transfer, without timings or repeats."""
    def get(log: list[Line]) -> list[tuple[str, Any]] | None:
        line = next((x for x in log if x.text.startswith(label)), None)
        if line is None:
            return None
        found = re.findall(r"'(MISSION_\w+)', \{'(?:seq|count|type)': (\d+)", line.text)
        # The script asks again every 0.5 s while it waits; a repeated answer to a repeated request is fine.
        return [m for i, m in enumerate(found) if i == 0 or m != found[i - 1]]
    return get


def items_back(log: list[Line]) -> list[tuple] | None:
    """The downloaded items, positions relative to the first (the vehicle is elsewhere on each run)."""
    rows = [x.text for x in log if x.text.startswith("  item back:")]
    if not rows:
        return None
    items = [ast.literal_eval(r.split(":", 1)[1].strip()) for r in rows]  # the script prints a dict literal
    x0, y0 = items[0]["x"], items[0]["y"]
    return [(d["seq"], d["frame"], d["command"], d["current"], d["autocontinue"], d["param2"], d["z"],
             d["x"] - x0, d["y"] - y0) for d in items]


# ---------------------------------------------------------------- comparisons --------------
def exact(a: Any, b: Any) -> bool:
    return a is not None and a == b


def within(abs_tol: float):
    return lambda a, b: a is not None and b is not None and abs(a - b) <= abs_tol


def rel(rel_tol: float):
    return lambda a, b: a is not None and b is not None and abs(a - b) <= rel_tol * abs(a)


def in_range(lo: float, hi: float):
    """The stub's value in [lo, hi] (PX4's own spread across runs), whatever this run gave."""
    return lambda a, b: b is not None and lo <= b <= hi


def same_items(a: list[tuple] | None, b: list[tuple] | None) -> bool:
    """Equal items; the offsets from item 0 within 2e-7 deg (the script rounds them from its own position)."""
    if a is None or b is None or len(a) != len(b):
        return False
    return all(x[:-2] == y[:-2] and abs(x[-2] - y[-2]) <= 2 and abs(x[-1] - y[-1]) <= 2 for x, y in zip(a, b))


def param_equal(a: str | None, b: str | None) -> bool:
    if a in (None, "None") or b in (None, "None"):
        return False
    return math.isclose(float(a), float(b), rel_tol=1e-6)


@dataclass(frozen=True)
class Step:
    name: str
    get: Callable[[list[Line]], Any]
    same: Callable[[Any, Any], bool]
    tolerance: str = "equal"


def ack(label: str) -> Callable[[list[Line]], Any]:
    return first(rf"^COMMAND_ACK {re.escape(label)}: (\w+)")


def mode_now(after: str) -> Callable[[list[Line]], Any]:
    return first(r"^mode now (\S+)", after=after)


STEPS: tuple[Step, ...] = (
    Step("boot.first_mode", first(r"^HEARTBEAT mode (\S+)"), exact),
    Step("boot.no_sensors_at_first", first(r"^SYS_STATUS .* present=(0x[0-9a-f]+)"), exact),
    Step("boot.healthy_at_s", sim_time_of(r"^SYS_STATUS .*prearm_ok=True"), within(0.5), "+-0.5 s sim"),
    *(Step(f"param.{n}", first(rf"^PARAM {n} = (\S+)"), param_equal, "equal (1e-6)") for n in PARAMS),
    Step("arm.first_try", ack("ARM try 1"), exact),
    Step("arm.denied_text_split_in_two", statustext_split, exact),
    Step("arm.accepted_at_s", arming_window, same_window(0.5), "the refusal ends at the same time +-0.5 s sim"),
    Step("arm.preflight_auto_disarm_s", first(r"^auto disarm ([\d.]+) s sim", convert=float), within(0.5), "+-0.5 s"),
    Step("arm.preflight_disarm_text", has("STATUSTEXT sev=6: Disarmed by auto preflight disarming\t"), exact),
    Step("ground.takeoff_disarmed_ack", ack("TAKEOFF while disarmed"), exact),
    Step("ground.takeoff_disarmed_mode", first(r"^mode now (.*)$"), exact),
    Step("ground.hold_ack", ack("HOLD on ground"), exact),
    Step("ground.offboard_no_setpoints_ack", ack("OFFBOARD, disarmed, no setpoints"), exact),
    Step("ground.offboard_no_setpoints_mode", mode_now("COMMAND_ACK OFFBOARD, disarmed, no setpoints"), exact),
    Step("ground.offboard_setpoints_ack", ack("OFFBOARD, disarmed, setpoints flowing"), exact),
    Step("ground.offboard_setpoints_mode", mode_now("COMMAND_ACK OFFBOARD, disarmed, setpoints flowing"), exact),
    Step("ground.disarmed_stream_stop_mode", mode_now("stop setpoints while disarmed"), exact),
    Step("ground.offboard_again_ack", ack("OFFBOARD again, setpoints flowing"), exact),
    Step("ground.arm_in_offboard_ack", ack("ARM in OFFBOARD with zero setpoints"), exact),
    Step("ground.zero_climb_stays_down", first(r"^mode now OFFBOARD armed=True alt=(\S+)", convert=lambda a: float(a) < 0.5),
         exact, "altitude < 0.5 m"),
    Step("ground.disarm_ack", ack("DISARM"), exact),
    Step("ground.hold_ack_2", ack("HOLD (AUTO.LOITER) on ground"), exact),
    Step("takeoff.param_set", first(r"^PARAM_SET MIS_TAKEOFF_ALT=20.0 -> (.*)$"), exact),
    Step("takeoff.arm_ack", ack("ARM"), exact),
    Step("takeoff.ack", ack("TAKEOFF (NaN params)"), exact),
    Step("takeoff.default_alt_text", has("STATUSTEXT sev=6: Using default takeoff altitude: 20.0 m\t"), exact),
    Step("takeoff.detected_text", has("STATUSTEXT sev=6: Takeoff detected\t"), exact),
    Step("takeoff.climb_to_19m_s", first(r"^climb to 19 m: ([\d.]+) s sim", convert=float), rel(0.10), "+-10 %"),
    Step("takeoff.hold_after", has("reached: HOLD after takeoff"), exact),
    Step("takeoff.settled_alt_m", first(r"^altitude settled at ([\d.]+) m", convert=float), within(0.3), "+-0.3 m"),
    Step("flight.landed_states", landed_states, exact, "the same sequence"),
    Step("offboard.in_air_ack", ack("OFFBOARD in air, setpoints flowing"), exact),
    Step("offboard.turn_speed_m_s", first(r"ground speed ([\d.]+) m/s, yawspeed", convert=float), rel(0.10), "+-10 %"),
    Step("offboard.turn_yawspeed_rad_s", first(r"yawspeed (-?[\d.]+) rad/s", convert=float), rel(0.10), "+-10 %"),
    Step("offboard.turn_alt_m", first(r"rad/s, alt ([\d.]+)", convert=float), within(1.0), "+-1 m"),
    Step("offboard.yaw_in_place_deg_s", first(r"^yawspeed now ([\d.]+) deg/s", convert=float), rel(0.10), "+-10 %"),
    Step("offboard.overspeed_m_s", first(r"^ground speed now ([\d.]+) m/s", convert=float), rel(0.10), "+-10 %"),
    Step("loss.target_mode", first(r"mode change OFFBOARD -> (\S+)"), exact),
    Step("loss.seen_after_s", first(r"mode change OFFBOARD -> \S+ ([\d.]+) s sim", convert=float), in_range(1.0, 2.1),
         "1.0-2.1 s sim (PX4: failsafe at 1.0-1.05 s, seen at the next 1 Hz heartbeat)"),
    Step("loss.failsafe_text", has("STATUSTEXT sev=2: Failsafe activated\t"), exact),
    Step("loss.heartbeat_state", failsafe_state, exact, "MAV_STATE equal (CRITICAL)"),
    Step("loss.auto_reentry_mode", first(r"^mode now (\S+) \([\d.]+ s sim after resuming\)"), exact),
    Step("loss.short_gap_mode", mode_now("gap of 0.7 s wall"), exact),
    Step("loss5.param_set", first(r"^PARAM_SET COM_OBL_RC_ACT=5 -> (.*)$"), exact),
    Step("loss5.target_mode", first(r"mode change OFFBOARD -> (\S+)", after="STOP setpoints with COM_OBL_RC_ACT=5"), exact),
    Step("loss5.seen_after_s", first(r"mode change OFFBOARD -> \S+ ([\d.]+) s sim", after="STOP setpoints with COM_OBL",
                                     convert=float), in_range(1.0, 2.1), "1.0-2.1 s sim"),
    Step("loss5.auto_reentry", auto_reentry_from_hold, exact, "OFFBOARD before the client asks"),
    Step("loss5.reenter_ack", ack("re-enter OFFBOARD from failsafe Hold"), exact),
    Step("loss5.param_reset", first(r"^PARAM_SET COM_OBL_RC_ACT=0 -> (.*)$"), exact),
    Step("mission.hold_ack", ack("HOLD"), exact),
    Step("mission.upload_exchange", exchange("upload exchange"), exact, "the same messages, timings aside"),
    Step("mission.download_exchange", exchange("download exchange"), exact, "the same messages"),
    Step("mission.items_back", items_back, lambda a, b: same_items(a, b), "equal fields; offsets from item 0 +-2e-7 deg"),
    Step("land.ack", ack("LAND"), exact),
    Step("land.text", has("STATUSTEXT sev=6: Landing at current position\t"), exact),
    Step("land.duration_s", first(r"^landing took ([\d.]+) s sim", convert=float), rel(0.10), "+-10 %"),
    Step("land.detected_text", has("STATUSTEXT sev=6: Landing detected\t"), exact),
    Step("land.disarm_text", has("STATUSTEXT sev=6: Disarmed by landing\t"), exact),
    Step("land.final_mode", first(r"^final mode (\S+)"), exact),
)


def compare(px4: list[Line], stub: list[Line]) -> dict[str, tuple[Any, Any]]:
    """Steps where the stub differs from PX4: name -> (PX4's value, the stub's)."""
    out = {}
    for step in STEPS:
        a, b = step.get(px4), step.get(stub)
        if not step.same(a, b):
            out[step.name] = (a, b)
    return out
