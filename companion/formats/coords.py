"""A geographic point read from a foreign file: one check for every importer.

QGroundControl writes ``[lat, lon]``, GeoJSON ``[lon, lat]`` (RFC 7946); both come out as the
mission's ``{lat_deg, lon_deg}``, or as the importer's own error naming where, in which order it
expected the pair, and what was wrong (missing, not a finite number, out of range).
"""

from __future__ import annotations

from typing import Any

from uav_model.mission_errors import echo
from uav_model.mission_read import finite


def geo_point(pair: Any, where: str, *, lon_first: bool, error: type[ValueError]) -> dict[str, float]:
    """``pair``'s first two items as finite degrees in range; ``lon_first``: GeoJSON's order."""
    order = "[lon, lat]" if lon_first else "[lat, lon]"
    a, b = (finite(v) for v in pair[:2]) if isinstance(pair, list) and len(pair) >= 2 else (None, None)
    if a is None or b is None:
        raise error(f"{where}: expected {order} in degrees (finite numbers), got {echo(pair)}")
    lat, lon = (b, a) if lon_first else (a, b)
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
        raise error(f"{where}: [{a:g}, {b:g}] is out of range for {order} in degrees")
    return {"lat_deg": lat, "lon_deg": lon}
