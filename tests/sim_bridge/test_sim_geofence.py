"""The stub enforces its stored geofence as PX4 does: GF_ACTION on a breach, STATUSTEXT, no arming outside.

The scenario tests run the stub as its own process (``python -m sim_bridge``) at 20x and fly it
from pymavlink over real UDP: upload a fence with the MAVLink mission protocol (mission_type
FENCE), take off, fly east in OFFBOARD into an exclusion circle, and watch the heartbeat's mode
and the STATUSTEXTs, as a ground station would.
"""

from __future__ import annotations

import math
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from uav_model.frames import local_to_geodetic
from uav_model.mission import parse_mission
from sim_bridge.vehicle.mission_protocol import FENCE, MissionItem
from sim_bridge.vehicle.px4 import FlightMode, decode_custom_mode
from sim_bridge.testing import free_udp_port_block, send_command, step_for
from sim_bridge.vehicle.geofence import BREACH_TEXT, DISTANCE_TEXT, fence_from_items

pytestmark = pytest.mark.timeout(60)

MISSION_YAML = """
name: geofence
origin: {lat_deg: 47.397742, lon_deg: 8.545594, alt_m: 488.0}
area: {x_min_m: 0, y_min_m: 0, x_max_m: 400, y_max_m: 400}
stations: {A: [100, 100], B: [300, 300]}
vehicles:
  - {name: a, start: A, goal: B, speed_m_s: 8, turn_radius_m: 10, cruise_alt_m: 5, initial_heading_deg: 0}
"""
WALL_S = 20.0
# An exclusion circle 40 m east of the station, and the area (plus 50 m) as the inclusion polygon.
EXCLUSION = ((160.0, 100.0), 20.0)
INCLUSION = ((-50.0, -50.0), (450.0, -50.0), (450.0, 450.0), (-50.0, 450.0))


@pytest.fixture(scope="module")
def mission():
    return parse_mission(MISSION_YAML, "geofence.yaml")


def fence_items(mission) -> list[tuple[int, float, float, float]]:
    """(command, param1, lat, lon) of the fence: the polygon's vertices, then the circle."""
    out = []
    for x, y in INCLUSION:
        lat, lon, _ = local_to_geodetic(mission.origin, x, y)
        out.append((mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, float(len(INCLUSION)), lat, lon))
    (cx, cy), r = EXCLUSION
    lat, lon, _ = local_to_geodetic(mission.origin, cx, cy)
    out.append((mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, r, lat, lon))
    return out


def stored(items) -> tuple[MissionItem, ...]:
    return tuple(MissionItem(i, mavlink.MAV_FRAME_GLOBAL_INT, cmd, 0, 1, p1, 0.0, 0.0, 0.0,
                             int(round(lat * 1e7)), int(round(lon * 1e7)), 0.0, FENCE)
                 for i, (cmd, p1, lat, lon) in enumerate(items))


def store_fence(v, gcs, items) -> None:
    """Upload fence items to a SimVehicle through its mission protocol (no sockets)."""
    v.handle(gcs.wire(gcs.enc.mission_count_encode(v.system_id, 1, len(items), FENCE)), "api")
    for seq, (cmd, p1, lat, lon) in enumerate(items):
        v.handle(gcs.wire(gcs.enc.mission_item_int_encode(
            v.system_id, 1, seq, mavlink.MAV_FRAME_GLOBAL_INT, cmd, 0, 1, p1, 0.0, 0.0, 0.0,
            int(round(lat * 1e7)), int(round(lon * 1e7)), 0.0, FENCE)), "api")
    assert len(v.missions.plan(FENCE)) == len(items)


# ---------------------------------------------------------------- pure ----------------------
def test_fence_items_become_zones_in_the_missions_frame(mission):
    fence = fence_from_items(stored(fence_items(mission)), mission.origin)
    assert len(fence.inclusion_polygons) == 1 and len(fence.exclusion_circles) == 1
    (c,) = fence.exclusion_circles
    assert (c.x_east_m, c.y_north_m, c.radius_m) == pytest.approx((160.0, 100.0, 20.0), abs=0.02)
    assert not fence.breached(100.0, 100.0)  # the station
    assert fence.breached(150.0, 100.0)  # inside the exclusion
    assert not fence.breached(139.0, 100.0)
    assert fence.breached(460.0, 100.0)  # outside the inclusion
    assert not fence.breached(449.0, 449.0)


def test_an_incomplete_polygon_is_ignored_and_no_inclusion_means_everywhere(mission):
    items = fence_items(mission)
    fence = fence_from_items(stored(items[:2] + items[-1:]), mission.origin)
    assert not fence.inclusion_polygons and len(fence.exclusion_circles) == 1
    assert not fence.breached(1000.0, 1000.0)


def test_no_arming_outside_the_fence_and_a_disarmed_vehicle_takes_no_action(mission, make_vehicle, gcs):
    v = make_vehicle(mission)
    lat, lon, _ = local_to_geodetic(mission.origin, 100.0, 100.0)  # an exclusion around the station itself
    store_fence(v, gcs, [(mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, 5.0, lat, lon)])
    texts = [m.text for m in step_for(v, 0.1) if m.get_type() == "STATUSTEXT"]
    assert texts == [BREACH_TEXT] and v.mode is FlightMode.HOLD and not v.geofence.breaches
    ack = send_command(v, gcs, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert ack.result == mavlink.MAV_RESULT_DENIED and not v.armed
    v.params.override("GF_ACTION", 0)  # PX4: no geofence checks at all
    assert send_command(v, gcs, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == mavlink.MAV_RESULT_ACCEPTED


def test_gf_predict_triggers_at_px4s_own_stopping_distance_ahead(mission, make_vehicle, gcs):
    v = make_vehicle(mission)
    store_fence(v, gcs, fence_items(mission))
    # 40 m short of the fence at 8 m/s: PX4's stopping distance (a stop at MPC_ACC_HOR 3 with jerk
    # MPC_JERK_AUTO 4 from MPC_ACC_HOR_MAX 5 forward, and one 0.2 s check) is 39.0 m
    v.state = replace(v.state, east_m=100.0, ve_m_s=8.0)
    v.params.override("GF_PREDICT", 1)
    assert not v.geofence.outside()
    v.params.override("MPC_JERK_AUTO", 2.0)  # a softer jerk: a longer stop
    assert v.geofence.outside()
    v.params.override("GF_PREDICT", 0)  # PX4's default: only the position counts
    assert not v.geofence.outside()
    v.state = replace(v.state, east_m=125.0)  # 15 m short: v^2 / (2 MPC_ACC_HOR) is 10.7 m, PX4's 39 m
    v.params.override("MPC_JERK_AUTO", 4.0)
    assert not v.geofence.outside()
    v.params.override("GF_PREDICT", 1)
    assert v.geofence.outside()


def test_gf_max_hor_dist_is_a_circle_around_home_with_its_own_words(mission, make_vehicle, gcs):
    v = make_vehicle(mission)
    home_n, home_e, _ = v.home_ned
    v.state = replace(v.state, north_m=home_n, east_m=home_e + 30.0)
    assert v.geofence.violation() is None  # no fence, no limit
    v.params.override("GF_MAX_HOR_DIST", 40.0)
    assert v.geofence.violation() is None
    v.state = replace(v.state, east_m=home_e + 41.0)
    assert v.geofence.violation() == DISTANCE_TEXT == "Geofence: exceeding maximum distance to Home"
    texts = [m.text for m in step_for(v, 0.1) if m.get_type() == "STATUSTEXT"]
    assert texts == [DISTANCE_TEXT]  # on the ground: said, no action
    ack = send_command(v, gcs, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert ack.result == mavlink.MAV_RESULT_DENIED and not v.armed


def test_the_fence_action_is_a_failsafe_in_the_heartbeat_until_the_client_takes_over(mission, make_vehicle, gcs):
    # PX4's heartbeat says MAV_STATE_CRITICAL while vehicle_status.failsafe holds: the structured
    # sign of the fence's Hold beside its text (PX4 streams no FENCE_STATUS).
    v = make_vehicle(mission, params={"MIS_TAKEOFF_ALT": 5.0})
    assert send_command(v, gcs, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == mavlink.MAV_RESULT_ACCEPTED
    nan = math.nan
    send_command(v, gcs, mavlink.MAV_CMD_NAV_TAKEOFF, nan, nan, nan, nan, nan, nan, nan)
    step_for(v, 30.0, until=lambda v: v.mode is FlightMode.HOLD and v.in_air)
    assert v.tele.heartbeat().system_status == mavlink.MAV_STATE_ACTIVE
    home_n, home_e, _ = v.home_ned
    v.params.override("GF_MAX_HOR_DIST", 1.0)
    v.state = replace(v.state, east_m=home_e + 5.0)
    texts = [m.text for m in step_for(v, 0.1) if m.get_type() == "STATUSTEXT"]
    assert texts == [DISTANCE_TEXT, "Failsafe activated"] and v.mode is FlightMode.HOLD
    assert v.tele.heartbeat().system_status == mavlink.MAV_STATE_CRITICAL
    v.params.override("GF_MAX_HOR_DIST", 0.0)
    send_command(v, gcs, mavlink.MAV_CMD_NAV_LAND, nan, nan, nan, nan, nan, nan, nan)  # the client takes over
    step_for(v, 0.1)
    assert v.mode is FlightMode.LAND and v.tele.heartbeat().system_status == mavlink.MAV_STATE_ACTIVE


# ---------------------------------------------------------------- over UDP ------------------
class Gcs:
    """A blocking pymavlink ground station on the vehicle's API port (the stub sends first)."""

    def __init__(self, port: int):
        self.conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=245, source_component=190)
        self.mode: tuple[int, int] | None = None
        self.texts = ""  # every STATUSTEXT chunk, as received (PX4 splits long texts)
        self.in_air = False

    def recv(self, timeout_s: float = 0.05):
        m = self.conn.recv_match(blocking=True, timeout=timeout_s)
        if m is None:
            return None
        kind = m.get_type()
        if kind == "HEARTBEAT" and m.get_srcComponent() == 1:
            self.mode = decode_custom_mode(m.custom_mode)
        elif kind == "STATUSTEXT":
            self.texts += m.text
        elif kind == "EXTENDED_SYS_STATE":
            self.in_air = m.landed_state == mavlink.MAV_LANDED_STATE_IN_AIR
        return m

    def wait(self, pred, what: str, timeout_s: float = WALL_S, each=None):
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            m = self.recv()
            if each is not None:
                each()
            if m is not None and pred(m):
                return m
        raise AssertionError(f"timed out waiting for {what}; texts: {self.texts}")

    def command(self, command: int, *params: float) -> int:
        p = (list(params) + [0.0] * 7)[:7]
        self.conn.mav.command_long_send(1, 1, command, 0, *p)
        ack = self.wait(lambda m: m.get_type() == "COMMAND_ACK" and m.command == command, f"ack of {command}", 5.0)
        return ack.result

    def upload_fence(self, items) -> None:
        self.conn.mav.mission_count_send(1, 1, len(items), FENCE)
        while True:
            m = self.wait(lambda m: m.get_type() in ("MISSION_REQUEST_INT", "MISSION_ACK"), "fence upload", 5.0)
            if m.get_type() == "MISSION_ACK":
                assert m.type == mavlink.MAV_MISSION_ACCEPTED and m.mission_type == FENCE
                return
            cmd, p1, lat, lon = items[m.seq]
            self.conn.mav.mission_item_int_send(1, 1, m.seq, mavlink.MAV_FRAME_GLOBAL_INT, cmd, 0, 1, p1, 0, 0, 0,
                                                int(round(lat * 1e7)), int(round(lon * 1e7)), 0.0, FENCE)

    def velocity_east(self, speed_m_s: float) -> None:
        mask = 0b0000_1101_1100_0111  # velocity only (position, acceleration, yaw, yaw rate ignored)
        self.conn.mav.set_position_target_local_ned_send(0, 1, 1, mavlink.MAV_FRAME_LOCAL_NED, mask,
                                                         0, 0, 0, 0.0, speed_m_s, 0.0, 0, 0, 0, 0, 0)


EXPECTED_MODE = {2: FlightMode.HOLD, 3: FlightMode.RTL, 5: FlightMode.LAND}


@pytest.mark.parametrize("gf_action", [2, 3, 5])
def test_flying_into_an_exclusion_takes_gf_action_over_udp(mission, tmp_path: Path, gf_action: int):
    path = tmp_path / "geofence.yaml"
    path.write_text(MISSION_YAML)
    port = free_udp_port_block(1)
    gcs = Gcs(port)
    proc = subprocess.Popen([sys.executable, "-m", "sim_bridge", str(path), "--speedup", "20", "--no-gcs",
                             "--api-port-base", str(port), "--param", f"GF_ACTION={gf_action}"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        gcs.wait(lambda m: m.get_type() == "HEARTBEAT", "the first heartbeat")
        gcs.upload_fence(fence_items(mission))
        end = time.monotonic() + WALL_S
        while gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) != mavlink.MAV_RESULT_ACCEPTED:
            assert time.monotonic() < end, gcs.texts  # PX4 refuses to arm during its first seconds
        nan = math.nan
        takeoff = gcs.command(mavlink.MAV_CMD_NAV_TAKEOFF, nan, nan, nan, nan, nan, nan, nan)
        assert takeoff == mavlink.MAV_RESULT_ACCEPTED
        gcs.wait(lambda m: gcs.in_air and gcs.mode == FlightMode.HOLD.value, "take-off complete")
        gcs.velocity_east(0.0)
        assert gcs.command(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                           *FlightMode.OFFBOARD.value) == mavlink.MAV_RESULT_ACCEPTED
        gcs.wait(lambda m: gcs.mode == FlightMode.OFFBOARD.value, "OFFBOARD")
        gcs.wait(lambda m: gcs.mode != FlightMode.OFFBOARD.value, "the breach action",
                 each=lambda: gcs.velocity_east(6.0))
        assert gcs.mode == EXPECTED_MODE[gf_action].value, (gcs.mode, gcs.texts)
        gcs.wait(lambda m: "Failsafe activated" in gcs.texts, "the failsafe text", 5.0)
        assert gcs.texts.index(BREACH_TEXT) < gcs.texts.index("Failsafe activated")
        # The vehicle stopped on its own: the local position stays outside the circle's far half.
        pos = gcs.wait(lambda m: m.get_type() == "LOCAL_POSITION_NED", "a position", 5.0)
        assert pos.y < EXCLUSION[0][0] + EXCLUSION[1], pos
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=10)
        gcs.conn.close()
    assert "Traceback" not in err


# ---------------------------------------------------------------- the companion dies ---------
DIES_YAML = """
name: companion-dies
origin: {lat_deg: 47.397742, lon_deg: 8.545594, alt_m: 488.0}
area: {x_min_m: 0, y_min_m: 0, x_max_m: 400, y_max_m: 400}
stations: {A: [100, 100], B: [350, 100]}
obstacles:
  - {id: hill, shape: circle, center: [200, 100], radius_m: 50}
vehicles:
  - {name: a, start: A, goal: B, speed_m_s: 8, turn_radius_m: 10, cruise_alt_m: 5}
"""


def _fly_to(v, gcs, east_m: float, north_m: float) -> None:
    """Offboard position setpoints (resent every 0.1 s, as a companion streams them) until there."""
    mask = 0b0000_1101_1111_1000  # position only
    for _ in range(600):
        v.handle(gcs.wire(gcs.enc.set_position_target_local_ned_encode(
            0, 1, 1, mavlink.MAV_FRAME_LOCAL_NED, mask, north_m, east_m, -5.0, 0, 0, 0, 0, 0, 0, 0, 0)), "api")
        if v.mode is not FlightMode.OFFBOARD:
            assert send_command(v, gcs, mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                                *FlightMode.OFFBOARD.value).result == mavlink.MAV_RESULT_ACCEPTED
        step_for(v, 0.1)
        if math.hypot(v.state.east_m - east_m, v.state.north_m - north_m) < 1.0:
            return
    raise AssertionError(f"never reached ({east_m}, {north_m}): at {v.position_enu_m}")


@pytest.mark.parametrize("gf_action", [2, 0])
def test_a_vehicle_whose_companion_dies_beyond_an_obstacle_is_stopped_by_its_fence(make_vehicle, gcs, gf_action):
    """The companion flies round the hill and dies; PX4's offboard-loss failsafe (Return) heads
    home straight through the hill. The companion's fence (the hill inflated, as `companion run`
    uploads it) stops the return at the inflated edge; without fence action the vehicle hits it."""
    mission = parse_mission(DIES_YAML, "dies.yaml")
    v = make_vehicle(mission, params={"GF_ACTION": gf_action, "MIS_TAKEOFF_ALT": 5.0})
    (hill,) = mission.world.obstacles
    lat, lon, _ = local_to_geodetic(mission.origin, *hill.center)
    store_fence(v, gcs, [(mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, hill.inflated_radius_m, lat, lon)])
    assert send_command(v, gcs, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == mavlink.MAV_RESULT_ACCEPTED
    nan = math.nan
    send_command(v, gcs, mavlink.MAV_CMD_NAV_TAKEOFF, nan, nan, nan, nan, nan, nan, nan)
    step_for(v, 30.0, until=lambda v: v.mode is FlightMode.HOLD and v.in_air)
    for east, north in ((100.0, 200.0), (300.0, 200.0), (300.0, 100.0)):  # round the hill
        _fly_to(v, gcs, east, north)
    assert v.collision_count == 0 and not v.geofence.breaches
    texts = [m.text for m in step_for(v, 60.0, until=lambda v: v.collision_count > 0 or v.geofence.breaches)
             if m.get_type() == "STATUSTEXT"]  # the companion is gone: no more setpoints
    assert v.offboard_losses, "the offboard-loss failsafe"
    if gf_action == 0:
        assert v.collision_count > 0  # Return flies home through the hill
        return
    assert v.geofence.breaches[0][1] == 2 and v.mode is FlightMode.HOLD, (v.mode, texts)
    step_for(v, 10.0)  # it brakes and holds
    assert v.collision_count == 0 and v.mode is FlightMode.HOLD
    assert math.hypot(v.state.east_m - 200.0, v.state.north_m - 100.0) > hill.size_m
