"""Pre-flight checks (companion.app.preflight), link identity (board, link probe): pure parts,
plus the probe over real UDP sockets on loopback."""

from __future__ import annotations

import asyncio
import math
import socket
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink

from companion.app.preflight import (Check, PreflightSettings, Severity, VehicleFacts, battery_need_pct, preflight)
from companion.errors import LinkConflict
from companion.vehicle.board import VehicleBoard, implausible_jump
from companion.vehicle.link_probe import frame_system_ids, probe_udpin, sender_system_id
from companion.vehicle.port import FlightMode, PoseSample
from uav_model.mission import load_mission

ROOT = Path(__file__).resolve().parents[2]
SMALL = load_mission(ROOT / "tests" / "data" / "small_swap.yaml")
PX4 = {"MPC_XY_VEL_MAX": 12.0, "MPC_ACC_HOR": 3.0, "MC_YAWRATE_MAX": 200.0, "COM_OF_LOSS_T": 1.0,
       "COM_OBL_RC_ACT": 0.0}  # PX4 SIH's defaults (../shared/px4-sih/README.md)


def facts(name: str, xy=None, heading_deg=None, **over) -> VehicleFacts:
    spec = SMALL.vehicle(name)
    x, y = xy if xy is not None else spec.start_enu_m
    base = dict(name=name, x_east_m=x, y_north_m=y,
                heading_enu_rad=math.radians(spec.initial_heading_deg if heading_deg is None else heading_deg),
                armed=False, in_air=False, home_ok=True, gps_fix_type=3, battery_pct=100.0, params=dict(PX4))
    base.update(over)
    return VehicleFacts(**base)


def run(fa=None, fb=None, **settings):
    f = {"a": fa or facts("a"), "b": fb or facts("b")}
    return preflight(SMALL, f, {"a": 972.0, "b": 953.0}, 0.1, PreflightSettings(**settings))


def refused(report, check: Check) -> list[str]:
    return [f.message for f in report.refusals if f.check is check]


def test_vehicles_at_their_stations_with_px4_defaults_pass():
    report = run()
    assert not report.refusals, report.refusals
    assert not report.replan


def test_a_vehicle_kilometres_away_is_refused_with_the_distance_and_the_fix():
    report = run(fa=facts("a", xy=(2000.0, 0.0)))
    (msg,) = refused(report, Check.STATION)
    assert "2000 m from station A" in msg and "--plan-from-current" in msg


def test_plan_from_current_moves_the_start_and_takes_the_real_heading():
    report = run(fa=facts("a", xy=(300.0, 50.0), heading_deg=90.0), plan_from_current=True)
    assert not report.refusals and report.replan
    a = report.mission.vehicle("a")
    assert a.start_enu_m == (300.0, 50.0) and a.initial_heading_deg == pytest.approx(90.0)


def test_station_tolerance_is_twice_the_arrival_radius_by_default():
    r = SMALL.safety.arrival_radius_m
    assert not refused(run(fa=facts("a", xy=(1.9 * r, 0.0))), Check.STATION)
    assert refused(run(fa=facts("a", xy=(2.1 * r, 0.0))), Check.STATION)
    assert not refused(run(fa=facts("a", xy=(2.1 * r, 0.0)), station_tolerance_m=5 * r), Check.STATION)


def test_px4s_turn_limit_derates_the_planned_turn_radius_with_the_numbers():
    report = run()
    a = report.mission.vehicle("a")
    # 10 m/s on a 30 m radius needs 3.33 m/s^2 > MPC_ACC_HOR 3: radius v^2 / a = 33.3 m
    assert a.turn_radius_m == pytest.approx(100.0 / 3.0)
    assert a.speed_m_s == 10.0
    (warn,) = [f for f in report.findings if f.vehicle == "a" and f.check is Check.TURN]
    assert warn.severity is Severity.INFO and "3.33 m/s^2 > MPC_ACC_HOR 3" in warn.message  # 11 % wider: not material


def test_a_turn_derate_that_widens_the_turns_materially_warns():
    gentle = dict(PX4, MPC_ACC_HOR=2.0)  # 10 m/s needs 50 m turns: 67 % wider than the mission's 30 m
    report = run(fa=facts("a", params=gentle))
    assert report.mission.vehicle("a").turn_radius_m == pytest.approx(50.0)
    (warn,) = [f for f in report.findings if f.vehicle == "a" and f.check is Check.TURN]
    assert warn.severity is Severity.WARN and "planning 50.0 m turns" in warn.message


def test_a_speed_limit_below_the_mission_derates_then_refuses():
    slow = dict(PX4, MPC_XY_VEL_MAX=8.0)
    a = run(fa=facts("a", params=slow)).mission.vehicle("a")
    assert a.speed_m_s == 8.0
    crawl = dict(PX4, MPC_XY_VEL_MAX=4.0)
    (msg,) = refused(run(fa=facts("a", params=crawl)), Check.SPEED)
    assert "MPC_XY_VEL_MAX 4 m/s" in msg


def test_missing_parameters_warn_not_refuse():
    report = run(fa=facts("a", params={}))
    assert not report.refusals
    warned = {f.check for f in report.findings if f.vehicle == "a" and f.severity is Severity.WARN}
    assert {Check.SPEED, Check.TURN, Check.OFFBOARD_LOSS} <= warned


def test_offboard_loss_actions():
    kept = dict(set_failsafe_hold=False)
    assert refused(run(fa=facts("a", params=dict(PX4, COM_OBL_RC_ACT=7.0)), **kept), Check.OFFBOARD_LOSS)
    assert not refused(run(fa=facts("a", params=dict(PX4, COM_OBL_RC_ACT=7.0))), Check.OFFBOARD_LOSS)  # set to 5
    assert not refused(run(fa=facts("a", params=dict(PX4, COM_OBL_RC_ACT=3.0)), **kept), Check.OFFBOARD_LOSS)
    assert refused(run(fa=facts("a", params=dict(PX4, COM_OF_LOSS_T=0.1))), Check.OFFBOARD_LOSS)


def test_home_gps_state_and_link_refusals():
    assert refused(run(fa=facts("a", home_ok=False)), Check.HOME)
    assert refused(run(fa=facts("a", gps_fix_type=2)), Check.GPS)
    assert not refused(run(fa=facts("a", gps_fix_type=None)), Check.GPS)  # not reported: a warning
    assert refused(run(fa=facts("a", armed=True)), Check.STATE)
    assert refused(run(fa=facts("a", link_anomaly="position jumped")), Check.LINK)


def test_battery_against_the_route():
    spec = SMALL.vehicle("b")
    need = battery_need_pct(spec, 953.0, PreflightSettings())
    assert 5.0 < need < 35.0  # the paper's weak UAV (35 %) can fly the small swap
    assert not refused(run(fb=facts("b", battery_pct=need + 1)), Check.BATTERY)
    (msg,) = refused(run(fb=facts("b", battery_pct=need - 1)), Check.BATTERY)
    assert f"needs ~{need:.0f} %" in msg


def _pose(t, x, y) -> PoseSample:
    return PoseSample(t, 0.0, x, y, 20.0, 0.0, 0.0, 0.0, 1)


def test_implausible_jump():
    assert implausible_jump(_pose(10.0, 0.0, 0.0), 5.0, 0.0, 10.5) is None  # 10 m/s
    assert implausible_jump(_pose(10.0, 0.0, 0.0), 30.0, 0.0, 13.0) is None  # after a 3 s gap
    assert "jumped 900 m" in implausible_jump(_pose(10.0, 0.0, 0.0), 900.0, 0.0, 10.05)


def test_board_flags_two_interleaved_vehicles_but_not_one_jump():
    async def main():
        board = VehicleBoard("a")
        t = 0.0
        glitch = []
        for i in range(10):  # one vehicle, one glitch
            t += 0.05
            p = await board.put_pose(t_sim_s=t, x_east_m=0.5 * i + (40.0 if i == 5 else 0.0), y_north_m=0.0,
                                     alt_rel_m=20.0, vx_east_m_s=0.0, vy_north_m_s=0.0, heading_enu_rad=0.0)
            glitch.append(p.plausible)
        assert board.status().link_anomaly is None
        assert glitch == [i != 5 for i in range(10)]  # only the glitch is kept out of the flown path
        mixed = []
        for i in range(6):  # two vehicles 900 m apart answering as one
            t += 0.05
            p = await board.put_pose(t_sim_s=t, x_east_m=900.0 * (i % 2), y_north_m=0.0, alt_rel_m=20.0,
                                     vx_east_m_s=0.0, vy_north_m_s=0.0, heading_enu_rad=0.0)
            mixed.append(p.plausible)
        assert "positions jumped" in board.status().link_anomaly
        assert mixed == [True, False, True, False, True, False]  # the other vehicle's samples, every one
        await board.put_status(mode=FlightMode.OFFBOARD)
        await board.put_status(mode=FlightMode.RETURN_TO_LAUNCH)
        await board.put_status(mode=FlightMode.OFFBOARD)
        st = board.status()
        assert st.mode_changes == 3 and st.last_other_mode is FlightMode.RETURN_TO_LAUNCH
        await board.put_text("Failsafe activated\t")
        assert board.status().failsafe_notices == 1
    asyncio.run(main())


def test_sender_system_id_reads_v1_and_v2_headers():
    assert sender_system_id(bytes([0xFD, 9, 0, 0, 7, 42, 1, 0, 0, 0]) + bytes(11)) == 42
    assert sender_system_id(bytes([0xFE, 9, 7, 3, 1, 0]) + bytes(11)) == 3
    assert sender_system_id(b"hello") is None


def test_frame_system_ids_follows_every_frame_of_a_datagram():
    """A spoofer cannot hide a frame behind another system's: every header is read."""
    other, ours = mavlink.MAVLink(None, 7, 1), mavlink.MAVLink(None, 1, 1)
    signed = mavlink.MAVLink(None, 3, 1)
    signed.signing.secret_key, signed.signing.sign_outgoing = bytes(32), True
    hb = (mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    data = (mavlink.MAVLink_heartbeat_message(*hb, 3).pack(other) + mavlink.MAVLink_heartbeat_message(*hb, 3).pack(signed)
            + mavlink.MAVLink_heartbeat_message(*hb, 3).pack(ours))
    assert frame_system_ids(data) == [7, 3, 1]
    assert frame_system_ids(data[:-3]) == [7, 3, 1]  # a truncated last frame still names its sender
    assert frame_system_ids(b"\x00" + data) == []


def test_probe_refuses_two_senders_with_one_system_id():
    heartbeat_from_1 = bytes([0xFD, 9, 0, 0, 0, 1, 1, 0, 0, 0]) + bytes(11)

    async def main():
        probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
        probe.close()
        senders = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(2)]

        async def send():
            for _ in range(20):
                for s in senders:
                    s.sendto(heartbeat_from_1, ("127.0.0.1", port))
                await asyncio.sleep(0.02)
        try:
            task = asyncio.create_task(send())
            with pytest.raises(LinkConflict, match="2 autopilots answer as system 1"):
                await probe_udpin(f"udpin://127.0.0.1:{port}", 1, "a", seconds=0.3)
            await task
            await probe_udpin(f"udpin://127.0.0.1:{port}", 2, "b", seconds=0.1)  # another id: no conflict
        finally:
            for s in senders:
                s.close()
    asyncio.run(main())


def test_one_clock_is_told_from_two_by_the_smallest_spread_and_the_speed_factor():
    from companion.app.readiness import clocks_agree
    # One sim-bridge at 20x on a busy machine: most samples jittered by tens of ms of delivery.
    assert clocks_agree([1.4, 0.9, 2.2, 0.3, 1.1], 20.0)
    assert clocks_agree([0.9, 0.95], 20.0)  # within 50 ms wall at 20x
    # Two PX4 instances booted seconds apart: never one clock, whatever the jitter.
    assert not clocks_agree([31.0, 30.2, 30.9], 20.0)
    assert not clocks_agree([3.0, 2.6], 20.0)
    # At 1x the floor of 0.5 s sim holds.
    assert not clocks_agree([0.9, 0.95], 1.0)
    assert clocks_agree([0.4], None)
