"""Shared setup for the stub's own tests: a GCS codec and SimVehicles driven without sockets."""

from __future__ import annotations

import pytest

from sim_bridge.vehicle.streams import API_PROFILE
from sim_bridge.testing import GcsCodec, boot
from sim_bridge.vehicle import SimVehicle


@pytest.fixture
def gcs() -> GcsCodec:
    return GcsCodec()


@pytest.fixture
def make_vehicle():
    """``make_vehicle(mission, index=0)``: a SimVehicle of ``mission.vehicles[index]`` with an "api" link,
    booted past PX4's preflight checks unless ``booted=False``."""

    def make(mission, index: int = 0, *, booted: bool = True, **kwargs) -> SimVehicle:
        v = SimVehicle(mission.vehicles[index], mission, **kwargs)
        v.add_link("api", API_PROFILE)
        if booted:
            boot(v)
        return v

    return make
