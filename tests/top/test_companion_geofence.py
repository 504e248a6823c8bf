"""The companion uploads the autopilot geofence and reads it back before anything arms.

Mostly in process: the vehicles are the stub's own (``companion.sitl.inprocess``), whose mission
protocol stores the FENCE plan and whose geofence enforces it, so these tests judge the upload by
what the autopilot holds, and the order by a recorder around the real adapter. One test does the
same through the MAVSDK adapter over real UDP.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink

from companion.app.fence import mission_fence, upload_and_verify_fence, verify_fence_readback
from companion.app.flight_plan import prepare
from companion.app.pilot import RunSettings
from companion.app.live_run import run_mission
from companion.cli import main
from companion.errors import GeofenceRefused
from companion.sitl.inprocess import open_inprocess_fleet
from companion.vehicle.mavsdk_open import open_mavsdk_vehicle
from companion.vehicle.port import GeoFenceZone
from uav_model.fence_margin import (exclusion_margin_m, fence_standoff_m, fence_warnings, keep_in_standoff_m,
                                   px4_braking_reach_m, rollout_box)
from uav_model.mission import parse_mission
from sim_bridge.bridge import SimOptions
from sim_bridge.vehicle.mission_protocol import FENCE
from sim_bridge.testing import sim_connection_url, stub_on_free_ports

pytestmark = pytest.mark.timeout(120)

MISSION_YAML = """
name: fenced
origin: {lat_deg: 47.397742, lon_deg: 8.545594, alt_m: 488.0}
area: {x_min_m: 0, y_min_m: 0, x_max_m: 400, y_max_m: 400, geofence_margin_m: 50}
stations: {A: [50, 50], B: [350, 350]}
obstacles:
  - {id: hill, shape: circle, center: [200, 200], radius_m: 40}
  - {id: barn, shape: rectangle, center: [300, 120], width_m: 40, height_m: 30}
vehicles:
  - {name: a, start: A, goal: B, speed_m_s: 10, turn_radius_m: 20, cruise_alt_m: 10}
  - {name: b, start: B, goal: A, speed_m_s: 10, turn_radius_m: 20, cruise_alt_m: 20}
"""
# 25 small twelve-sided sheds: their inflation is thinner than the fence standoff, so each is
# uploaded as its footprint, 12 vertices, 300 items in all: more than the autopilot stores (the
# stub's FENCE capacity is 256 items).
def _shed(i: int, j: int) -> str:
    cx, cy = 260 + 16 * i, 20 + 16 * j
    ring = ", ".join(f"[{cx + 5 * math.cos(k * math.pi / 6):.2f}, {cy + 5 * math.sin(k * math.pi / 6):.2f}]"
                     for k in range(12))
    return f"  - {{id: shed{i}{j}, shape: polygon, vertices: [{ring}]}}"


SHEDS = "\n".join(_shed(i, j) for i in range(5) for j in range(5))
TOO_BIG_YAML = MISSION_YAML.replace("vehicles:\n", SHEDS + "\nvehicles:\n")


class Recorder:
    """The real in-process adapter, with the order of the port calls written down."""

    def __init__(self, inner, calls: list[str]):
        self._inner = inner
        self._calls = calls

    def __getattr__(self, name):
        attr = getattr(self._inner, name)
        if name in ("upload_fence", "download_fence", "upload_route", "arm", "takeoff"):
            async def call(*args, **kwargs):
                self._calls.append(f"{self._inner.name}:{name}")
                return await attr(*args, **kwargs)
            return call
        return attr


def _run(yaml_text: str, geofence: bool = True):
    mission = parse_mission(yaml_text, "fenced.yaml")
    plan = prepare(mission)
    plan = type(plan)(plan.mission, plan.variant, plan.routes, geofence=geofence)
    calls: list[str] = []
    lines: list[str] = []

    async def go():
        async with open_inprocess_fleet(mission) as fleet:
            @contextlib.asynccontextmanager
            async def opener(spec, url):
                async with fleet.open_vehicle(spec, url) as v:
                    yield Recorder(v, calls)
            try:
                result = await run_mission(plan, fleet.connections(), RunSettings(), None, lines.append,
                                           open_vehicle=opener)
            except GeofenceRefused as exc:
                result = exc
            return result, {v.name: v.sim for v in fleet.vehicles}
    result, sims = asyncio.run(go())
    return mission, result, sims, calls, lines


def test_the_fence_is_uploaded_and_read_back_before_arming_and_the_flight_stays_inside():
    mission, result, sims, calls, lines = _run(MISSION_YAML)
    assert result.success, (result.reason, result.message)
    for name, sim in sims.items():
        order = [c.split(":")[1] for c in calls if c.startswith(name + ":")]
        assert order.index("upload_fence") < order.index("download_fence") < order.index("arm"), order
        stored = sim.missions.plan(FENCE)
        commands = [it.command for it in stored]
        assert commands[:4] == [mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION] * 4  # the area + margin
        # The hill (40 m, 8 m of inflation): its exclusion lies the standoff inside the keep-out,
        # never inside the footprint.
        hill_fence_m = 40.0 + exclusion_margin_m(mission.world.obstacles[0], fence_standoff_m(mission))
        assert commands[4] == mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION and stored[4].param1 == pytest.approx(hill_fence_m)
        assert set(commands[5:]) == {mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION}  # the barn
        assert not sim.geofence.breaches  # the flight never entered an inflated obstacle
        assert any(f"{name}: geofence uploaded and read back (the area and 2 obstacles, " in line for line in lines)
    # The autopilot's zones are the .plan's: the geometry in the stub is the mission's inflated obstacles.
    fence = sims["a"].geofence.fence
    (circle,) = fence.exclusion_circles
    assert (circle.x_east_m, circle.y_north_m) == pytest.approx((200.0, 200.0), abs=0.02)
    (ring,) = fence.exclusion_polygons
    barn = ring.polygon
    inflated = mission.world.obstacles[1].inflated
    footprint = mission.world.obstacles[1].footprint
    assert barn.within(inflated.buffer(0.05)) and barn.area >= 0.999 * footprint.area


def test_no_fence_uploads_nothing():
    _, result, sims, calls, _ = _run(MISSION_YAML, geofence=False)
    assert result.success
    assert not any("fence" in c for c in calls)
    assert all(sim.missions.plan(FENCE) == () for sim in sims.values())


def test_a_fence_the_autopilot_cannot_store_refuses_the_flight_and_nothing_arms(caplog):
    caplog.set_level(logging.INFO, logger="companion")
    _, result, sims, calls, _ = _run(TOO_BIG_YAML)
    assert isinstance(result, GeofenceRefused), result
    assert "MAV_MISSION_NO_SPACE" in str(result) and "--no-fence" in str(result)
    assert not any(c.endswith(":arm") for c in calls), calls
    assert all(not sim.armed and sim.modes.armed_t is None for sim in sims.values())
    assert "Armed by" not in caplog.text


def test_cli_refuses_in_one_line_with_exit_2(tmp_path: Path, capsys, companion_logger):
    path = tmp_path / "too_big.yaml"
    path.write_text(TOO_BIG_YAML)
    assert main(["run", str(path), "--in-process"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("companion: refused: vehicle ") and "nothing was armed" in err[0]


def test_a_read_back_that_differs_is_refused():
    mission = parse_mission(MISSION_YAML, "fenced.yaml")
    sent = mission_fence(mission)
    verify_fence_readback("a", sent, sent)
    moved = GeoFenceZone(inclusion=False, center_deg=(sent[1].center_deg[0] + 1e-6, sent[1].center_deg[1]),
                         radius_m=sent[1].radius_m)
    with pytest.raises(GeofenceRefused, match="zone 1 read back as a circle at"):
        verify_fence_readback("a", sent, (sent[0], moved, sent[2]))
    with pytest.raises(GeofenceRefused, match="read back has 2 zones, uploaded 3"):
        verify_fence_readback("a", sent, sent[:2])


def test_the_mavsdk_adapter_uploads_and_reads_back_the_same_fence_over_udp():
    mission = parse_mission(MISSION_YAML, "fenced.yaml")
    plan = prepare(mission)
    lines: list[str] = []

    async def go():
        async with stub_on_free_ports(mission, SimOptions(speedup=20.0), gcs=False) as sim:
            spec = mission.vehicles[0]
            async with open_mavsdk_vehicle(spec.name, spec.system_id, sim_connection_url(sim, 0), mission.origin,
                                           connect_timeout_s=10.0) as v:
                await upload_and_verify_fence(v, plan, lines.append)
                got = await v.download_fence()
            return sim.vehicle(0).missions.plan(FENCE), got
    stored, got = asyncio.run(asyncio.wait_for(go(), 60.0))
    verify_fence_readback("a", mission_fence(mission), got)
    assert len(stored) == sum(1 if z.is_circle else len(z.vertices_deg) for z in got)
    assert any("geofence uploaded and read back" in line for line in lines), lines


# -- the fence tells the truth: over real UDP, the stub as its own process, the companion's MAVSDK ---

SMALL_FIELD = Path(__file__).resolve().parents[1] / "data" / "small_field.yaml"


def test_the_standoff_puts_each_exclusion_inside_the_keep_out_and_never_inside_the_footprint():
    mission = parse_mission(MISSION_YAML.replace("radius_m: 40", "radius_m: 100"), "fenced.yaml")
    s = fence_standoff_m(mission)
    assert s == pytest.approx(10.0 ** 2 / (2 * 3.0))  # v^2 / (2 MPC_ACC_HOR), PX4's default 3 m/s^2
    hill, barn = mission.world.static_obstacles
    _, circle, ring = mission_fence(mission)
    assert circle.radius_m == pytest.approx(100.0 + 20.0 - s)  # 20 % inflation (20 m) less the standoff
    assert len(ring.vertices_deg) == 4  # the barn's 5 m inflation is thinner than the standoff: its footprint
    assert [w for w in fence_warnings(mission) if "barn" in w] and not [w for w in fence_warnings(mission)
                                                                        if "hill" in w or "geofence_margin" in w]


def _stop_by_steps(v: float, a0: float, a_max: float, jerk: float, dt: float = 1e-4) -> float:
    """A jerk-limited stop flown in small steps: the deceleration ramps to a_max from a0 forward, and
    back to nothing just as the speed runs out."""
    x, acc = 0.0, a0
    while v > 0.0:
        acc = acc + jerk * dt if acc < 0.0 and v <= acc * acc / (2.0 * jerk) else max(acc - jerk * dt, -a_max)
        v += acc * dt
        x += v * dt
    return x


def test_the_rollouts_keep_px4s_own_stopping_distance_and_the_lag_from_the_inclusion_fence():
    # PX4's navigator tests its fence at its own stopping distance ahead (GF_PREDICT 1); with its
    # defaults (MPC_ACC_HOR 3, MPC_ACC_HOR_MAX 5, MPC_JERK_AUTO 4, one 0.2 s check) that is 50.7 m
    # at 10 m/s, three times v^2 / (2 MPC_ACC_HOR).
    for v in (0.5, 3.0, 10.0, 12.0):
        assert px4_braking_reach_m(v) == pytest.approx(_stop_by_steps(v, 5.0, 3.0, 4.0) + 0.2 * v, abs=0.01), v
    assert px4_braking_reach_m(10.0) == pytest.approx(50.74, abs=0.01)
    assert px4_braking_reach_m(0.0) == 0.0
    mission = parse_mission(MISSION_YAML.replace("geofence_margin_m: 50", "geofence_margin_m: 100"), "m.yaml")
    assert keep_in_standoff_m(mission) == pytest.approx(px4_braking_reach_m(10.0))
    grow = 100.0 - px4_braking_reach_m(10.0) - 2.0 * 10.0  # the multicopter trails its rollouts ~2 s
    assert rollout_box(mission, mission.vehicles[0]) == pytest.approx((-grow, -grow, 400.0 + grow, 400.0 + grow))
    # the paper's unicycle stops as it is told: the braking distance alone
    ideal = parse_mission(MISSION_YAML.replace("geofence_margin_m: 50", "geofence_margin_m: 100") + "plant: unicycle\n",
                          "m.yaml")
    assert keep_in_standoff_m(ideal) == pytest.approx(fence_standoff_m(ideal))
    # a margin thinner than the standoff and the lag: the rollouts keep to the area
    assert rollout_box(parse_mission(MISSION_YAML, "m.yaml"), mission.vehicles[0]) == (0.0, 0.0, 400.0, 400.0)


def _breach_texts(stub, name: str) -> list[str]:
    return [t for t in stub.vehicle(name).statustext if t.startswith("Geofence:")]


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_the_small_field_flies_with_the_fence_uploaded_and_never_breaches(sitl, companion):
    # A user's 800 x 600 m field: the routes skim three inflated obstacles and the area's edge.
    stub = sitl(SMALL_FIELD, speedup=20)
    run = companion(stub, timeout_s=240)
    assert run.exit_code == 0, run.tail
    assert run.summary["success"] and run.summary["failsafes"] == [], run.summary
    for name in ("a", "b"):
        assert f"{name}: geofence uploaded and read back (the area and 3 obstacles" in run.stdout
        assert _breach_texts(stub, name) == [], name
    area = stub.mission.world
    for row in run.flight_log():
        if row["phase"] == "offboard" and row["x_m"]:
            assert area.x_min_m - 1.0 <= float(row["x_m"]) <= area.x_max_m + 1.0, row
            assert area.y_min_m - 1.0 <= float(row["y_m"]) <= area.y_max_m + 1.0, row


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_a_fence_breach_fails_the_run_as_geofence_with_the_failsafe_listed(sitl, companion):
    # The operator narrows the fence in flight (GF_MAX_HOR_DIST, on the GCS link): a is beyond it at
    # once. PX4 (and the stub) say "Geofence: exceeding maximum distance to Home",
    # "Failsafe activated", and Hold. That is a breach, not an offboard loss to resume from.
    stub = sitl(SMALL_FIELD, speedup=20)
    live = companion.start(stub)
    stub.wait_for_mode("a", "OFFBOARD", timeout_s=90)
    stub.wait_for_clock(stub.mode_times("a", "OFFBOARD")[0] + 15.0, timeout_s=60)
    sysid = stub.mission.vehicle("a").system_id

    async def narrow() -> None:
        stub.recorder.send(sysid, mavlink.MAVLink_param_set_message(
            sysid, 1, b"GF_MAX_HOR_DIST", 40.0, mavlink.MAV_PARAM_TYPE_REAL32))
    stub.telemetry.call(narrow())
    run = live.wait(180)
    assert run.exit_code == 1, run.tail
    assert run.summary["reason"] == "geofence" and not run.summary["success"], run.summary
    fences = [f for f in run.summary["failsafes"] if f["cause"] == "geofence"]
    assert [(f["vehicle"], f["mode"], f["recovered"]) for f in fences] == [("a", "HOLD", False)], run.summary
    assert fences[0]["t_mission_s"] > 15.0 and "maximum distance to Home" in fences[0]["notice"]
    assert "FAILED (geofence)" in run.stdout and "failsafe: a entered HOLD at" in run.stdout
    assert "a: autopilot fell back to HOLD (offboard loss)" not in run.stdout, run.stdout[-3000:]
    assert _breach_texts(stub, "a")
    modes = stub.modes("a")
    assert "OFFBOARD" not in modes[modes.index("HOLD", modes.index("OFFBOARD")):], modes  # not fought
