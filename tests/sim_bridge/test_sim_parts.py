"""The stub's small pure parts: stream scheduler, sim clock, fault injection, ground truth."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mavlink

from uav_model.mission import parse_mission
from sim_bridge.clock import ClockError, SimClock
from sim_bridge.faults import Blackout, FaultConfig, FaultSpecError, LinkFaults
from sim_bridge.streams import API_PROFILE, StreamProfile, StreamScheduler
from sim_bridge.truth import CollisionChecker

pytestmark = pytest.mark.timeout(30)

HB = mavlink.MAVLINK_MSG_ID_HEARTBEAT
POS = mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED


def count_due(sched, msg_id, speedup, wall_seconds, tick_wall_s=0.004):
    n = 0
    for k in range(int(wall_seconds / tick_wall_s)):
        wall = k * tick_wall_s
        n += sched.due(wall * speedup, wall).count(msg_id)
    return n


def test_streams_run_in_sim_time_up_to_the_wall_cap():
    profile = StreamProfile({POS: 10.0, HB: 1.0}, max_wall_rate_hz=50.0)
    assert count_due(StreamScheduler(profile), POS, 1.0, 10.0) == pytest.approx(100, abs=2)  # 10 Hz at 1x
    assert count_due(StreamScheduler(profile), POS, 4.0, 10.0) == pytest.approx(400, abs=4)  # 40 Hz wall at 4x
    assert count_due(StreamScheduler(profile), POS, 20.0, 10.0) == pytest.approx(500, abs=5)  # capped at 50 Hz wall


@pytest.mark.parametrize("name, px4_hz", [("ATTITUDE", 100), ("GLOBAL_POSITION_INT", 50), ("LOCAL_POSITION_NED", 30),
                                          ("SYS_STATUS", 5), ("EXTENDED_SYS_STATE", 5), ("GPS_RAW_INT", 8)])
def test_api_link_has_px4_sitl_rates_in_sim_time_and_a_wall_cap(name, px4_hz):
    """PX4 SIH's measured onboard-link rates (../shared/px4-sih/README.md), capped on the wall clock."""
    msg_id = getattr(mavlink, f"MAVLINK_MSG_ID_{name}")
    assert count_due(StreamScheduler(API_PROFILE), msg_id, 1.0, 5.0, tick_wall_s=0.002) == pytest.approx(5 * px4_hz, rel=0.03)
    at_20x = count_due(StreamScheduler(API_PROFILE), msg_id, 20.0, 5.0, tick_wall_s=0.002)
    assert at_20x == pytest.approx(5 * min(20 * px4_hz, API_PROFILE.max_wall_rate_hz), rel=0.03)


def test_heartbeat_keeps_one_hertz_of_wall_time_at_any_speed():
    slow = StreamProfile({HB: 1.0}, max_wall_rate_hz=50.0)
    assert count_due(StreamScheduler(slow), HB, 0.1, 10.0) == pytest.approx(10, abs=1)  # sim 1 Hz would be 0.1 Hz
    off = StreamScheduler(slow)
    off.set_interval(HB, None)
    assert count_due(off, HB, 1.0, 10.0) == pytest.approx(10, abs=1)  # even when turned off


def test_stream_interval_can_be_changed_and_reset():
    sched = StreamScheduler(StreamProfile({POS: 10.0}, max_wall_rate_hz=1000.0))
    sched.set_interval(POS, 0.5)
    assert count_due(sched, POS, 1.0, 10.0) == pytest.approx(20, abs=1)
    sched.reset_default(POS)
    assert sched.interval_s(POS) == pytest.approx(0.1)


def test_clock_runs_fixed_steps_at_the_speed_factor_and_slips_when_starved():
    clock = SimClock(speedup=10.0, dt_s=0.02, wall_start_s=100.0, max_lag_steps=50)
    n = clock.steps_due(100.1)  # 1 s of sim time
    assert n == 50
    for _ in range(n):
        clock.advance()
    assert clock.sim_time_s == pytest.approx(1.0)
    assert clock.steps_due(100.1) == 0
    assert clock.steps_due(110.0) == 50 and clock.slipped_s > 0  # 99 s behind: run 50 steps, slip the rest
    assert clock.achieved_speedup(110.0) < 10.0
    with pytest.raises(ClockError):
        SimClock(speedup=0.0, dt_s=0.02, wall_start_s=0.0)
    with pytest.raises(ClockError):
        SimClock(speedup=float("nan"), dt_s=0.02, wall_start_s=0.0)


def test_loss_is_seeded_per_link_and_repeatable():
    cfg = FaultConfig(loss_p=0.3)
    first = LinkFaults(cfg, 7, "a/api/out")
    second = LinkFaults(cfg, 7, "a/api/out")
    other = LinkFaults(cfg, 8, "a/api/out")
    run1 = [first.verdict(0.0) for _ in range(2000)]
    run2 = [second.verdict(0.0) for _ in range(2000)]
    run3 = [other.verdict(0.0) for _ in range(2000)]
    assert run1 == run2 and run1 != run3
    assert run1.count(None) / 2000 == pytest.approx(0.3, abs=0.04)


def test_latency_and_blackout_windows():
    faults = LinkFaults(FaultConfig(latency_ms=150.0, blackouts=(Blackout(10.0, 5.0),)), 0, "x")
    assert faults.verdict(9.99) == pytest.approx(0.15)
    assert faults.verdict(10.0) is None and faults.verdict(14.99) is None
    assert faults.verdict(15.0) == pytest.approx(0.15)
    faults.add_blackout(Blackout(20.0, 1.0))
    assert faults.verdict(20.5) is None
    assert Blackout.parse("30:5") == Blackout(30.0, 5.0)
    for bad in ("30", "a:b", "-1:5", "3:0"):
        with pytest.raises(FaultSpecError):
            Blackout.parse(bad)
    with pytest.raises(FaultSpecError):
        FaultConfig(loss_p=1.5)


WORLD_YAML = """
area: {x_min_m: 0, y_min_m: 0, x_max_m: 1000, y_max_m: 1000}
stations: {A: [0, 0], B: [1000, 1000]}
obstacles:
  - {id: thin, shape: rectangle, center: [500, 500], width_m: 1, height_m: 200}
  - id: mover
    shape: circle
    center: [100, 800]
    radius_m: 20
    motion: {type: shuttle, to: [900, 800], speed_m_s: 10}
vehicles:
  - {name: a, start: A, goal: B}
"""


@pytest.fixture(scope="module")
def checker():
    return CollisionChecker(parse_mission(WORLD_YAML, "world.yaml").world)


def test_segment_crossing_a_thin_obstacle_between_samples_is_a_hit(checker):
    # Both ends are outside the 1 m wall; only the segment touches it.
    assert checker.hits(480.0, 500.0, 520.0, 500.0, 0.0, 1.0) == ["thin"]
    assert checker.hits(480.0, 700.0, 520.0, 700.0, 0.0, 1.0) == []


def test_moving_obstacle_is_checked_where_it_is_at_that_time(checker):
    # The disc starts at x = 100 and moves +x at 10 m/s: at t = 30 s it is centred at x = 400.
    assert checker.hits(400.0, 800.0, 400.0, 800.0, 30.0, 30.02) == ["mover"]
    assert checker.hits(400.0, 800.0, 400.0, 800.0, 0.0, 0.02) == []
    # A hovering vehicle the disc sweeps over within one (long) step is hit, though it is clear
    # of the disc at both ends of the step.
    assert checker.hits(400.0, 800.0, 400.0, 800.0, 25.0, 35.0) == ["mover"]


ENVELOPE_YAML = """
area: {x_min_m: 0, y_min_m: 0, x_max_m: 1000, y_max_m: 1000}
stations: {A: [0, 0], B: [1000, 1000]}
obstacles:
  - {id: still, shape: triangle, center: [500, 500], circumradius_m: 60, rotation_deg: 17}
  - id: shuttle
    shape: rectangle
    center: [200, 300]
    width_m: 40
    height_m: 80
    rotation_deg: 30
    motion: {type: shuttle, to: [700, 450], speed_m_s: 7}
  - id: orbit
    shape: circle
    center: [600, 800]
    radius_m: 35
    motion: {type: orbit, pivot: [500, 750], speed_m_s: 6, clockwise: true}
  - id: patrol
    shape: polygon
    vertices: [[820, 150], [880, 170], [860, 230], [800, 210]]
    motion: {type: patrol, waypoints: [[900, 500], [700, 600]], speed_m_s: 5}
vehicles:
  - {name: a, start: A, goal: B}
"""


@settings(max_examples=300, deadline=None)
@given(x0=st.floats(-100, 1100), y0=st.floats(-100, 1100), dx=st.floats(-30, 30), dy=st.floats(-30, 30),
       t=st.floats(0, 2000), dt=st.floats(0.001, 2.0))
def test_fast_collision_check_agrees_with_the_plain_geometry(x0, y0, dx, dy, t, dt):
    """The envelope shortcut and the offset cache never change an answer."""
    from shapely.geometry import LineString, Point

    world = _envelope_world()
    fast = CollisionChecker(world)
    fast.hits(x0, y0, x0, y0, t - dt, t)  # warm the offset cache at t, as the previous step would
    got = fast.hits(x0, y0, x0 + dx, y0 + dy, t, t + dt)
    want = []
    for o in world.obstacles:
        a, b = o.offset_at(t), o.offset_at(t + dt)
        p0, p1 = (x0 - a[0], y0 - a[1]), (x0 + dx - b[0], y0 + dy - b[1])
        geom = Point(p0) if p0 == p1 else LineString([p0, p1])
        if o.footprint.intersects(geom):
            want.append(o.id)
    assert got == want


_WORLD_CACHE: list = []


def _envelope_world():
    if not _WORLD_CACHE:
        _WORLD_CACHE.append(parse_mission(ENVELOPE_YAML, "envelope.yaml").world)
    return _WORLD_CACHE[0]


# ---------------------------------------------------------------- PX4 look-alikes ---------
def test_statustext_is_split_as_px4_splits_it():
    """Measured on PX4 SIH: event texts end in a tab; a long one arrives as two chunks."""
    from typing import Any, NamedTuple

    from sim_bridge.statustext import StatustextSplitter

    class Out(NamedTuple):
        msg: Any
        link: str | None = None

    mav = mavlink.MAVLink(None, 1, 1)
    split = StatustextSplitter(mav)
    hb = Out(mav.heartbeat_encode(2, 12, 0, 0, 3, 3))
    long_text = "Arming denied: Resolve system health failures first"
    out = split.expand([hb, Out(mav.statustext_encode(2, long_text.encode()), "api"),
                        Out(mav.statustext_encode(6, b"Armed by external command")),
                        Out(mav.statustext_encode(2, b"Preflight Fail: heading estimate not stable"))])
    assert out[0] is hb
    texts = [(o.msg.text, o.msg.id, o.msg.chunk_seq, o.link) for o in out[1:]]
    first_id = texts[0][1]
    assert first_id != 0 and texts[:2] == [("Arming denied: Resolve system health failures firs", first_id, 0, "api"),
                                           ("t\t", first_id, 1, "api")]
    assert texts[2:] == [("Armed by external command\t", 0, 0, None),
                         ("Preflight Fail: heading estimate not stable", 0, 0, None)]
    for o in out:  # every chunk fits the wire
        o.msg.pack(mav)


def test_px4_sim_battery_drains_to_its_floor_when_armed_and_refills_when_disarmed():
    from sim_bridge.energy import px4_sim_battery_pct

    pct, t = 100.0, 0.0
    while t < 20.0:
        pct, t = px4_sim_battery_pct(pct, True, 0.02, 60.0, 50.0), t + 0.02
    assert pct == pytest.approx(100.0 - 100.0 * 20.0 / 60.0, abs=0.05)  # SIM_BAT_DRAIN 60 s per 100 %
    for _ in range(5000):
        pct = px4_sim_battery_pct(pct, True, 0.02, 60.0, 50.0)
    assert pct == 50.0  # SIM_BAT_MIN_PCT
    assert px4_sim_battery_pct(pct, False, 0.02, 60.0, 50.0) == 100.0


def test_sys_status_reports_no_sensors_then_no_gps_then_healthy_at_boot():
    from sim_bridge.health import HEALTH_SETTLED_S, PREARM_CHECK, SENSORS_PRESENT_S, sensor_bits

    gps = mavlink.MAV_SYS_STATUS_SENSOR_GPS
    assert sensor_bits(0.0, True)[0] == 0
    present, _, health = sensor_bits(SENSORS_PRESENT_S + 0.1, True)
    assert present & mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO and not present & gps and not health & PREARM_CHECK
    present, enabled, health = sensor_bits(HEALTH_SETTLED_S, True)
    assert present & gps and health & gps and health & PREARM_CHECK and enabled == present
    assert not sensor_bits(HEALTH_SETTLED_S + 10.0, False)[2] & PREARM_CHECK  # e.g. battery too low
