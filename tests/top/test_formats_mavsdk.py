"""MAVSDK's own QGroundControl importer (stricter than QGC's documentation) accepts our .plan."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.mission_raw import MissionRawAsync

from companion.app.flight_plan import prepare
from companion.app.fence import mission_fence
from companion.formats.qgc_plan import plan_document
from sim_bridge.testing import sim_connection_url, stub_on_free_ports
from uav_model.mission import load_mission

ROOT = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.slow


def _document(plan, vehicle):
    """The .plan document of ``vehicle``, from what the app uploads."""
    return plan_document(plan.mission, vehicle, plan.waypoints(vehicle), mission_fence(plan.mission))


def test_mavsdk_imports_our_plan_with_route_and_fences(tmp_path):
    mission = load_mission(ROOT / "missions" / "moving_obstacles.yaml")
    plan = prepare(mission)
    vehicle = mission.vehicles[0]
    path = tmp_path / f"{vehicle.name}.plan"
    doc = _document(plan, vehicle)
    path.write_text(json.dumps(doc, indent=2))

    async def scenario():
        async with stub_on_free_ports(mission, gcs=False) as sim:
            async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as sdk:
                await sdk.add_any_connection(sim_connection_url(sim, 0))
                system = await sdk.first_autopilot(timeout_s=10.0)
                assert system is not None
                return await MissionRawAsync(system).import_qgroundcontrol_mission(str(path))

    data = asyncio.run(asyncio.wait_for(scenario(), 60))
    waypoints = plan.waypoints(vehicle)
    commands = [item.command for item in data.mission_items]
    assert commands == [22] + [16] * len(waypoints) + [21]  # take-off, the route, land
    for item, wp in zip(data.mission_items[1:-1], waypoints):
        assert (item.x, item.y) == (round(wp.lat_deg * 1e7), round(wp.lon_deg * 1e7))
    # PX4 fences: one item per polygon vertex, one per circle.
    fence = doc["geoFence"]
    expected = sum(len(p["polygon"]) for p in fence["polygons"]) + len(fence["circles"])
    assert len(data.geofence_items) == expected > 0
