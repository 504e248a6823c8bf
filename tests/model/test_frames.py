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


def test_local_to_geodetic_matches_pymap3d_inverse_over_the_whole_area():
    """Over a 10 x 10 km area around the origin, our inverse agrees with pymap3d's own
    (vectorised) enu2geodetic to well under a millimetre, and the old spherical projection
    (R = 6,378,137 m, azimuthal equidistant) would have been off by metres."""
    import numpy as np
    import pymap3d

    xs, ys = np.meshgrid(np.linspace(-5000, 5000, 21), np.linspace(-5000, 5000, 21))
    lat_ref, lon_ref, _ = pymap3d.enu2geodetic(xs.ravel(), ys.ravel(), 0.0 * xs.ravel(),
                                               ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_m)
    worst_m = 0.0
    for x, y, la, lo in zip(xs.ravel(), ys.ravel(), lat_ref, lon_ref):
        lat, lon, _ = frames.local_to_geodetic(ORIGIN, float(x), float(y))
        e, n, _ = pymap3d.geodetic2enu(lat, lon, ORIGIN.alt_m, la, lo, ORIGIN.alt_m)
        worst_m = max(worst_m, math.hypot(e, n))
    # pymap3d's inverse returns the tangent-plane point itself (up = 0, ~2 m above flat ground at
    # 5 km); ours keeps the origin's altitude, so the two differ only by that drop's lean: < 1 cm.
    assert worst_m < 1e-2
    # The tangent plane is not a sphere: 5 km east, a 6378 km sphere misplaces the point by metres.
    x_sph = 5000.0 * 6_378_137.0 / (6_378_137.0 / math.sqrt(1 - 6.69438e-3 * math.sin(math.radians(ORIGIN.lat_deg)) ** 2))
    assert abs(x_sph - 5000.0) > 1.0


def test_geodetic_to_local_distances_are_geodesic():
    """East-west and north-south distances from the origin equal WGS-84 geodesic lengths (Vincenty)."""
    from pymap3d.vincenty import vdist

    sea_level = frames.GeoOrigin(ORIGIN.lat_deg, ORIGIN.lon_deg, 0.0)  # geodesics lie on the ellipsoid
    for lat, lon in ((ORIGIN.lat_deg + 0.02, ORIGIN.lon_deg), (ORIGIN.lat_deg, ORIGIN.lon_deg + 0.03),
                     (ORIGIN.lat_deg - 0.015, ORIGIN.lon_deg - 0.02)):
        x, y, _ = frames.geodetic_to_local(sea_level, lat, lon)
        dist, _ = vdist(ORIGIN.lat_deg, ORIGIN.lon_deg, lat, lon)
        assert math.hypot(x, y) == pytest.approx(float(dist), rel=2e-6)  # plane vs ellipsoid: < 1 cm at 3 km


def test_geodetic_to_local_is_pymap3ds_tangent_plane():
    """The plain-float transform gives pymap3d's geodetic2enu east and north to a micrometre."""
    import pymap3d

    origin = GeoOrigin(47.397742, 8.545594, 488.0)
    for dlat, dlon in [(0.0, 0.0), (0.03, -0.04), (-0.05, 0.05), (0.001, 0.0007), (-0.02, -0.03)]:
        lat, lon = origin.lat_deg + dlat, origin.lon_deg + dlon
        e, n, _ = pymap3d.geodetic2enu(lat, lon, origin.alt_m, origin.lat_deg, origin.lon_deg, origin.alt_m)
        x, y, z = frames.geodetic_to_local(origin, lat, lon, 500.0)
        assert (x, y, z) == pytest.approx((float(e), float(n), 12.0), abs=1e-6)
