"""The harness's judge without sockets: MAVLink messages fed to the recorder by hand, then the
assertions a scenario test makes. Each assertion must catch what happens *between* samples."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest
from pymavlink.dialects.v20 import common as mavlink

from uav_model.frames import local_to_geodetic
from uav_model.mission import Mission
from companion.testing.telemetry import Telemetry
from companion.testing.recorder import TelemetryRecorder, mode_name

ROOT = Path(__file__).resolve().parents[2]
REFERENCE = ROOT / "missions" / "paper_reference.yaml"  # fire: circle r=500 at (707.11, 707.11)

MODES = {"HOLD": 4 << 16 | 3 << 24, "TAKEOFF": 4 << 16 | 2 << 24, "OFFBOARD": 6 << 16, "LAND": 4 << 16 | 6 << 24,
         "POSCTL": 3 << 16, "MISSION": 4 << 16 | 4 << 24, "RTL": 4 << 16 | 5 << 24}


class Feed:
    """Messages from vehicles, as the recorder would decode them, at chosen wall times."""

    def __init__(self, mission: Mission):
        self.rec = TelemetryRecorder()
        self.mission = mission
        self.telemetry = Telemetry(self.mission, REFERENCE, SimpleNamespace(recorder=self.rec, port=0))
        self._enc: dict[int, mavlink.MAVLink] = {}

    def send(self, sysid: int, msg, wall: float, tap: bool = False) -> None:
        enc = self._enc.setdefault(sysid, mavlink.MAVLink(None, srcSystem=sysid, srcComponent=1))
        buf = msg.pack(enc)
        if tap:
            self.rec._on_tap_datagram(buf, ("127.0.0.1", 1))
            return
        decoded = mavlink.MAVLink(None).parse_buffer(buf)[0]
        self.rec._on_message(decoded, wall)

    def mode(self, sysid: int, mode: str, wall: float, armed: bool = True) -> None:
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mavlink.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
        self.send(sysid, mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4,
                                                           base, MODES[mode], mavlink.MAV_STATE_ACTIVE, 3), wall)

    def at(self, sysid: int, t_s: float, x_m: float, y_m: float, wall: float | None = None, tap: bool = False) -> None:
        """A LOCAL_POSITION_NED (ENU x east, y north) stamped t_s, arriving at ``wall`` (default t_s / 20)."""
        msg = mavlink.MAVLink_local_position_ned_message(int(round(t_s * 1000)), y_m, x_m, -50.0, 0, 0, 0)
        self.send(sysid, msg, t_s / 20.0 if wall is None else wall, tap)

    def path(self, sysid: int, points: list[tuple[float, float, float]]) -> None:
        for t, x, y in points:
            self.at(sysid, t, x, y)


@pytest.fixture
def feed(reference_mission) -> Feed:
    return Feed(reference_mission)


def _fly(feed: Feed, sysid: int, points, modes=(("HOLD", 0.0), ("OFFBOARD", 0.0))) -> None:
    for mode, t in modes:
        feed.mode(sysid, mode, t / 20.0)
    feed.path(sysid, points)


def test_px4_custom_modes_are_named():
    assert {name: mode_name(word) for name, word in MODES.items()} == {n: n for n in MODES}
    assert mode_name(9 << 16) == "PX4(9,0)"


def test_a_mode_change_is_placed_on_the_sim_clock_between_stamped_samples(feed):
    feed.mode(1, "HOLD", 0.0)
    feed.at(1, 10.0, 0, 0, wall=1.0)
    feed.mode(1, "OFFBOARD", 1.5)  # halfway, in wall time, between samples stamped 10 s and 30 s
    feed.at(1, 30.0, 0, 0, wall=2.0)
    assert feed.telemetry.mode_times("a", "OFFBOARD") == [pytest.approx(20.0)]
    assert feed.telemetry.modes("a") == ["HOLD", "OFFBOARD"]


def test_the_track_since_departure_starts_at_the_departure_itself(feed):
    feed.mode(1, "TAKEOFF", 0.0)
    feed.at(1, 10.0, 0.0, 0.0, wall=1.0)
    feed.at(1, 12.0, 0.0, 0.0, wall=2.0)
    feed.mode(1, "OFFBOARD", 2.5)
    feed.at(1, 14.0, 20.0, 0.0, wall=3.0)  # departure at 13 s: halfway between the samples
    tr = feed.telemetry.track("a", since_mode="OFFBOARD")
    assert tr.t_s.tolist() == pytest.approx([13.0, 14.0]) and tr.x_m.tolist() == pytest.approx([10.0, 20.0])
    with pytest.raises(ValueError, match="never reported mode LAND"):
        feed.telemetry.track("a", since_mode="LAND")


def test_tapped_and_gcs_positions_make_one_track_without_duplicates(feed):
    feed.mode(1, "OFFBOARD", 0.0)
    for t in (0.0, 2.0, 4.0):
        feed.at(1, t, 10 * t, 0.0)
    for t in (0.2, 2.0, 2.2, 3.8):
        feed.at(1, t, 10 * t, 0.0, tap=True)
    assert feed.telemetry.track("a").t_s.tolist() == [0.0, 0.2, 2.0, 2.2, 3.8, 4.0]


def test_clearance_catches_a_step_that_cuts_through_an_obstacle_and_names_it(feed):
    # Both samples are far outside the fire circle; the step between them crosses it.
    _fly(feed, 1, [(0.0, 0.0, 707.11), (100.0, 1414.0, 707.11)])
    _fly(feed, 2, [(0.0, 3181.98, 3181.98), (100.0, 3181.98, 3181.98)])
    with pytest.raises(AssertionError, match=r"vehicle 'a' entered obstacle 'fire' \(true footprint\) between t=0.0"):
        feed.telemetry.assert_clearance()


def test_clearance_margin(feed):
    _fly(feed, 1, [(0.0, 0.0, 0.0), (100.0, 3181.98, 0.0)])  # passes 207 m south of the fire's edge
    _fly(feed, 2, [(0.0, 3181.98, 3181.98), (100.0, 3181.98, 3181.98)])
    feed.telemetry.assert_clearance()
    feed.telemetry.assert_clearance(min_m=200.0)
    with pytest.raises(AssertionError, match=r"came within 207\.\d m \(minimum 250 m\) of obstacle 'fire'"):
        feed.telemetry.assert_clearance(min_m=250.0)


def test_separation_is_checked_between_samples(feed):
    # Head-on along y = 3000: 1000 m apart at both samples' ends, they pass through each other between.
    _fly(feed, 1, [(0.0, 1000.0, 3000.0), (100.0, 2000.0, 3000.0)])
    _fly(feed, 2, [(0.0, 2000.0, 3000.0), (100.0, 1000.0, 3000.0)])
    with pytest.raises(AssertionError, match=r"vehicles 'a' and 'b' came within 0\.0 m .*minimum 50 m"):
        feed.telemetry.assert_separation()
    feed.telemetry.assert_clearance()  # nothing else is wrong


def test_geofence(feed):
    _fly(feed, 1, [(0.0, 0.0, 0.0), (10.0, -150.0, 0.0), (20.0, -250.0, 0.0)])  # the fence is 200 m out
    _fly(feed, 2, [(0.0, 3181.98, 3181.98), (20.0, 3181.98, 3181.98)])
    with pytest.raises(AssertionError, match=r"vehicle 'a' left the geofence at t=20\.0 s.*fence x -200\.\.3381\.98"):
        feed.telemetry.assert_geofence()


def test_arrival_counts_a_step_through_the_disc_and_reports_a_near_miss(feed):
    a_goal, b_goal = feed.mission.vehicle("a").goal_enu_m, feed.mission.vehicle("b").goal_enu_m
    # a's samples are 30 m either side of its goal; the step between them passes through it.
    _fly(feed, 1, [(0.0, a_goal[0] - 30.0, a_goal[1]), (6.0, a_goal[0] + 30.0, a_goal[1])])
    _fly(feed, 2, [(0.0, 1500.0, 1500.0), (6.0, b_goal[0] + 25.0, b_goal[1])])  # 25 m short
    feed.telemetry.assert_arrived("a")
    with pytest.raises(AssertionError, match=r"vehicle 'b' never reached station A \(within 20 m\): closest 25\.0 m"):
        feed.telemetry.assert_arrived()


def test_modes_in_order(feed):
    for i, mode in enumerate(["HOLD", "TAKEOFF", "OFFBOARD", "HOLD", "OFFBOARD", "LAND"]):
        feed.mode(1, mode, float(i))
    feed.telemetry.assert_modes_in_order("a", "TAKEOFF", "HOLD", "LAND")
    with pytest.raises(AssertionError, match="expected modes LAND -> OFFBOARD in this order, reported HOLD -> TAKEOFF"):
        feed.telemetry.assert_modes_in_order("a", "LAND", "OFFBOARD")


def test_adsb_reports_come_back_in_the_mission_frame(feed):
    feed.mode(1, "OFFBOARD", 0.0)
    feed.at(1, 10.0, 0, 0, wall=1.0)
    feed.at(1, 30.0, 0, 0, wall=2.0)
    lat, lon, _ = local_to_geodetic(feed.mission.origin, 1000.0, 2000.0)
    feed.send(1, mavlink.MAVLink_adsb_vehicle_message(0xAD0001, int(lat * 1e7), int(lon * 1e7), 0, 0, 9000, 400, 0,
                                                      b"truck", 0, 1, 0, 0), 1.5)
    (report,) = feed.telemetry.traffic("a")["truck"]
    assert (report.t_s, report.x_m, report.y_m) == pytest.approx((20.0, 1000.0, 2000.0), abs=0.02)
    assert (report.course_deg, report.speed_m_s) == (90.0, 4.0)


def test_an_unheard_vehicle_is_a_clear_failure(feed):
    with pytest.raises(AssertionError, match=r"vehicle 'b' \(system 2\) was never heard"):
        feed.telemetry.vehicle("b")
