"""companion.app.failsafe: PX4's offboard-loss failsafe (a notice, then RTL or Hold) against an
operator's mode change (no notice), in the orders PX4 and MAVSDK deliver them."""

from __future__ import annotations

import asyncio
import dataclasses

from companion.app.failsafe import FailsafeWatch, ModeVerdict
from companion.vehicle.board import VehicleBoard
from companion.vehicle.port import FlightMode, VehicleStatus

GRACE_WALL_S = 1.0
OFFBOARD = VehicleStatus(armed=True, mode=FlightMode.OFFBOARD, mode_changes=3)


def _to(st: VehicleStatus, mode: FlightMode) -> VehicleStatus:
    other = mode if mode is not FlightMode.OFFBOARD else st.last_other_mode
    return dataclasses.replace(st, mode=mode, mode_changes=st.mode_changes + 1, last_other_mode=other)


def _notice(st: VehicleStatus, clock_s: float) -> VehicleStatus:
    return dataclasses.replace(st, failsafe_notices=st.failsafe_notices + 1, last_failsafe_t_sim_s=clock_s)


def test_the_failsafe_text_heard_in_offboard_before_the_rtl_heartbeat_is_a_failsafe():
    # PX4: "Failsafe activated" at once, the mode at the next 1 Hz heartbeat; samples still in OFFBOARD between.
    watch = FailsafeWatch(OFFBOARD)
    st = _notice(OFFBOARD, 100.0)
    assert watch.judge(st, 100.2, 0.0, GRACE_WALL_S, False) is ModeVerdict.FLYING
    st = _to(st, FlightMode.RETURN_TO_LAUNCH)
    assert watch.judge(st, 101.5, 0.1, GRACE_WALL_S, False) is ModeVerdict.RECOVER
    # Still in RTL while the uplink is down: the same failsafe, not a new override.
    assert watch.judge(st, 103.0, 5.0, GRACE_WALL_S, False) is ModeVerdict.RECOVER
    st = _to(st, FlightMode.OFFBOARD)  # PX4 re-entered OFFBOARD: counted once, by the recovery
    assert watch.judge(st, 104.0, 6.0, GRACE_WALL_S, False) is ModeVerdict.FLYING


def test_a_text_that_comes_after_the_mode_within_the_grace_is_a_failsafe():
    watch = FailsafeWatch(OFFBOARD)
    st = _to(OFFBOARD, FlightMode.HOLD)
    assert watch.judge(st, 50.0, 10.0, GRACE_WALL_S, False) is ModeVerdict.WAIT
    st = _notice(st, 50.0)
    assert watch.judge(st, 50.1, 10.3, GRACE_WALL_S, False) is ModeVerdict.RECOVER


def test_hold_or_rtl_without_any_failsafe_evidence_is_an_operator_override():
    for mode in (FlightMode.HOLD, FlightMode.RETURN_TO_LAUNCH):
        watch = FailsafeWatch(OFFBOARD)
        st = _to(OFFBOARD, mode)
        assert watch.judge(st, 50.0, 10.0, GRACE_WALL_S, False) is ModeVerdict.WAIT
        assert watch.judge(st, 50.1, 10.0 + GRACE_WALL_S, GRACE_WALL_S, False) is ModeVerdict.OVERRIDE


def test_other_modes_are_an_override_at_once():
    watch = FailsafeWatch(OFFBOARD)
    st = _notice(_to(OFFBOARD, FlightMode.LAND), 50.0)  # COM_OBL_RC_ACT 4: not recoverable either
    assert watch.judge(st, 50.0, 0.0, GRACE_WALL_S, False) is ModeVerdict.OVERRIDE


def test_a_notice_is_used_once_and_goes_stale():
    watch = FailsafeWatch(OFFBOARD)
    st = _to(_notice(OFFBOARD, 10.0), FlightMode.HOLD)
    assert watch.judge(st, 10.5, 0.0, GRACE_WALL_S, False) is ModeVerdict.RECOVER
    st = _to(st, FlightMode.OFFBOARD)
    assert watch.judge(st, 12.0, 1.0, GRACE_WALL_S, False) is ModeVerdict.FLYING
    # Later an operator switches to Hold: the old notice does not excuse it.
    st = _to(st, FlightMode.HOLD)
    assert watch.judge(st, 13.0, 2.0, GRACE_WALL_S, False) is ModeVerdict.WAIT
    assert watch.judge(st, 13.0, 2.0 + GRACE_WALL_S, GRACE_WALL_S, False) is ModeVerdict.OVERRIDE
    # A notice from before OFFBOARD was entered, or too old, does not count either.
    old = _to(_notice(OFFBOARD, 5.0), FlightMode.HOLD)
    assert FailsafeWatch(_notice(OFFBOARD, 5.0)).judge(old, 6.0, 0.0, GRACE_WALL_S, False) is ModeVerdict.WAIT
    assert FailsafeWatch(OFFBOARD).judge(old, 60.0, 0.0, GRACE_WALL_S, False) is ModeVerdict.WAIT


def test_our_own_telemetry_gap_explains_the_failsafe():
    watch = FailsafeWatch(OFFBOARD)
    st = _to(OFFBOARD, FlightMode.RETURN_TO_LAUNCH)
    assert watch.judge(st, 50.0, 0.0, GRACE_WALL_S, True) is ModeVerdict.RECOVER


def test_back_in_offboard_by_itself_is_a_failsafe_that_is_over():
    watch = FailsafeWatch(OFFBOARD)
    st = _to(_to(OFFBOARD, FlightMode.RETURN_TO_LAUNCH), FlightMode.OFFBOARD)  # both between two samples
    assert watch.judge(st, 50.0, 0.0, GRACE_WALL_S, False) is ModeVerdict.RESUMED
    assert watch.judge(st, 50.1, 0.1, GRACE_WALL_S, False) is ModeVerdict.FLYING


def _breach(st: VehicleStatus, clock_s: float) -> VehicleStatus:
    text = "Geofence violation: approaching or outside geofence"
    return dataclasses.replace(st, fence_notices=st.fence_notices + 1, last_fence_t_sim_s=clock_s, last_fence_text=text)


def test_a_geofence_hold_is_a_fence_event_not_an_offboard_loss():
    # The stub and PX4: "Geofence violation: ..." then "Failsafe activated", then Hold (GF_ACTION 2).
    watch = FailsafeWatch(OFFBOARD)
    st = _to(_notice(_breach(OFFBOARD, 60.0), 60.0), FlightMode.HOLD)
    assert watch.judge(st, 60.5, 0.0, GRACE_WALL_S, True) is ModeVerdict.FENCE
    # The fence's own "Failsafe activated" is used up: it does not explain a later Hold as a loss.
    st = _to(_to(st, FlightMode.OFFBOARD), FlightMode.HOLD)
    assert watch.judge(st, 61.0, 0.1, GRACE_WALL_S, False) is ModeVerdict.WAIT


def test_a_breach_heard_while_recovering_or_still_in_offboard_is_a_fence_event():
    # The failsafe text first (recovery begun), the breach notice a moment later.
    watch = FailsafeWatch(OFFBOARD)
    st = _to(_notice(OFFBOARD, 60.0), FlightMode.HOLD)
    assert watch.judge(st, 60.1, 0.0, GRACE_WALL_S, False) is ModeVerdict.RECOVER
    assert watch.judge(_breach(st, 60.2), 60.3, 0.1, GRACE_WALL_S, False) is ModeVerdict.FENCE
    # GF_ACTION 1 (warning only): the vehicle stays in OFFBOARD, and it is still a breach.
    watch = FailsafeWatch(OFFBOARD)
    assert watch.judge(_breach(OFFBOARD, 70.0), 70.0, 0.0, GRACE_WALL_S, False) is ModeVerdict.FENCE


def test_breach_notices_from_before_offboard_do_not_count():
    before = _breach(OFFBOARD, 10.0)
    watch = FailsafeWatch(before)
    assert watch.judge(before, 50.0, 0.0, GRACE_WALL_S, False) is ModeVerdict.FLYING


def test_the_board_counts_breach_notices_but_not_an_arming_refusal():
    async def go():
        board = VehicleBoard("a")
        await board.note_clock(12.5)
        await board.put_text("Arming denied: Geofence violation: approaching or outside geofence")
        assert board.status().fence_notices == 0
        await board.put_text("Geofence violation: exceeding maximum distance to Home\t")  # PX4 appends a tab
        await board.put_text("Failsafe activated")
        return board.status()
    st = asyncio.run(go())
    assert (st.fence_notices, st.last_fence_t_sim_s, st.failsafe_notices) == (1, 12.5, 1)
    assert st.last_fence_text == "Geofence violation: exceeding maximum distance to Home"


def test_the_board_hears_px4s_own_breach_statustext_and_not_a_mission_check():
    # What PX4 (the build in ../shared/px4-sih) sends as STATUSTEXT: "Geofence: ..."; "Geofence
    # violation: ..." is its event's wording. A mission's waypoint check is not a breach.
    async def go():
        board = VehicleBoard("a")
        await board.note_clock(3.0)
        await board.put_text("Geofence violation for waypoint 1\t")
        assert board.status().fence_notices == 0
        await board.put_text("Geofence: approaching or outside geofence\t")
        await board.put_text("Geofence: exceeding maximum altitude above Home")
        return board.status()
    st = asyncio.run(go())
    assert st.fence_notices == 2 and st.last_fence_text == "Geofence: exceeding maximum altitude above Home"


def test_a_hold_at_the_uploaded_fence_without_any_text_is_a_fence_event():
    # No notice heard (lost, or worded otherwise): the Hold comes while the vehicle is at its fence.
    watch = FailsafeWatch(OFFBOARD)
    at = "inside the exclusion fence of obstacle 'mast'"
    assert watch.judge(OFFBOARD, 40.0, 0.0, GRACE_WALL_S, False, at) is ModeVerdict.FLYING  # still flying: no action
    st = _to(OFFBOARD, FlightMode.HOLD)
    assert watch.judge(st, 41.0, 0.1, GRACE_WALL_S, False, at) is ModeVerdict.FENCE
    assert watch.fence_where == at
    # Away from the fence, the same Hold without a text is what it was before: wait for evidence.
    watch = FailsafeWatch(OFFBOARD)
    assert watch.judge(st, 41.0, 0.1, GRACE_WALL_S, False, None) is ModeVerdict.WAIT


def test_the_fence_geometry_is_the_uploaded_one_and_names_where_the_vehicle_is():
    from pathlib import Path

    from companion.app.fence import FenceGeometry
    from uav_model.mission import load_mission
    mission = load_mission(Path(__file__).resolve().parents[1] / "data" / "small_field.yaml")
    fence = FenceGeometry(mission)
    # The pond (r 70 m, inflation 14 m < the 16.7 m standoff): its exclusion is the footprint.
    assert fence.breach(420.0 + 70.0 + 4.0, 330.0, 5.0) == "4.0 m from the exclusion fence of obstacle 'pond'"
    assert fence.breach(420.0 + 60.0, 330.0, 5.0) == "inside the exclusion fence of obstacle 'pond'"
    assert fence.breach(420.0 + 70.0 + 6.0, 330.0, 5.0) is None
    assert fence.breach(-30.0, 300.0, 5.0) == "5.0 m outside the inclusion fence (the area)"  # area + 25 m margin
    assert fence.breach(-22.0, 300.0, 5.0) == "3.0 m inside the inclusion fence (the area)"
    assert fence.breach(100.0, 300.0, 5.0) is None


def test_px4s_own_breach_wording_counts_and_its_waypoint_warning_does_not():
    async def go():
        board = VehicleBoard("a")
        await board.note_clock(40.0)
        await board.put_text("Geofence violation for waypoint 3\t")  # at the route upload, PX4 SIH main
        assert board.status().fence_notices == 0
        await board.put_text("Geofence: approaching or outside geofence\t")  # the breach, as PX4 SIH main says it
        return board.status()
    st = asyncio.run(go())
    assert st.fence_notices == 1 and st.last_fence_text == "Geofence: approaching or outside geofence"
