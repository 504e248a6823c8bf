"""Frame conventions: ENU math headings vs NED yaw, and the geodetic projection."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from uav_model import frames
from uav_model.frames import GeoOrigin

ORIGIN = GeoOrigin(47.397742, 8.545594, 488.0)


@pytest.mark.parametrize(
    ("theta_enu_deg", "yaw_ned_deg"),
    [(0.0, 90.0), (90.0, 0.0), (45.0, 45.0), (-135.0, -135.0), (180.0, -90.0)],
)
def test_heading_conversion(theta_enu_deg, yaw_ned_deg):
    yaw = frames.enu_heading_to_ned_yaw(math.radians(theta_enu_deg))
    assert math.degrees(yaw) == pytest.approx(yaw_ned_deg)
    assert frames.ned_yaw_to_enu_heading(yaw) == pytest.approx(frames.wrap_pi(math.radians(theta_enu_deg)))


def test_yaw_rate_flips_sign():
    assert frames.enu_yaw_rate_to_ned(0.3) == -0.3
    assert frames.ned_yaw_rate_to_enu(frames.enu_yaw_rate_to_ned(0.3)) == 0.3


def test_position_axes():
    assert frames.enu_to_ned(1.0, 2.0, 3.0) == (2.0, 1.0, -3.0)
    assert frames.ned_to_enu(*frames.enu_to_ned(1.0, 2.0, 3.0)) == (1.0, 2.0, 3.0)


def test_north_is_north_on_the_globe():
    lat, lon, _ = frames.local_to_geodetic(ORIGIN, 0.0, 1000.0)
    assert lat > ORIGIN.lat_deg and lon == pytest.approx(ORIGIN.lon_deg)
    lat, lon, _ = frames.local_to_geodetic(ORIGIN, 1000.0, 0.0)
    assert lon > ORIGIN.lon_deg and lat == pytest.approx(ORIGIN.lat_deg, abs=1e-4)


@given(st.floats(-5000, 5000), st.floats(-5000, 5000), st.floats(-100, 500))
def test_geodetic_round_trip_is_centimetre_exact(x, y, z):
    lat, lon, alt = frames.local_to_geodetic(ORIGIN, x, y, z)
    x2, y2, z2 = frames.geodetic_to_local(ORIGIN, lat, lon, alt)
    assert math.hypot(x2 - x, y2 - y) < 0.01
    assert z2 == pytest.approx(z)
