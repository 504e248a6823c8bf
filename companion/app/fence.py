"""The autopilot's own geofence: what the companion uploads before arming, and its read-back check.

    mission_fence(mission) -> (GeoFenceZone, ...)   the area + margin as the inclusion polygon, then
                                                    every static obstacle as an exclusion, the
                                                    fence standoff inside the planner's keep-out
    upload_and_verify_fence(vehicle, plan, report)  upload (mission_type FENCE), download, compare

One source of truth: the QGroundControl ``.plan`` export (:mod:`companion.formats.qgc_plan`) writes
exactly these zones. The standoff is :func:`uav_model.fence_margin.fence_standoff_m`, the braking
distance the planner's margins keep from the fence: an exclusion is the footprint grown by the
inflation less the standoff (never less than the footprint). A circle stays a circle; a polygon is
buffered with round joins of about ``FENCE_VERTEX_SPACING_M`` per vertex, whose chords lie inside
the offset curve, so they never come closer to the planner's keep-out. Moving obstacles are not
fenced (a fence cannot move).

:class:`FenceGeometry` answers, from a position, whether the vehicle is at the uploaded fence: with
a failsafe mode change that is the autopilot's fence action, whatever its words (PX4 sends no
FENCE_STATUS; its STATUSTEXT is "Geofence: approaching or outside geofence").

If the autopilot refuses the fence, or reads back something else, the flight is refused
(:class:`~companion.errors.GeofenceRefused`) before anything is armed; ``companion run --no-fence``
skips the step for autopilots without fence support.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

from shapely.geometry import Point, Polygon

from uav_model import frames
from uav_model.fence_margin import exclusion_margin_m, fence_standoff_m, fence_warnings
from uav_model.mission import Mission
from uav_model.world import Obstacle
from companion.errors import CommandRefused, GeofenceRefused, MissionUploadError
from companion.vehicle.port import GeoFenceZone, Vehicle

if TYPE_CHECKING:
    from companion.app.flight_plan import FlightPlan

FENCE_VERTEX_SPACING_M = 25.0  # a curved inflated corner becomes straight runs about this long
SIMPLIFY_M = 0.05  # vertices closer than this to a straight run are dropped
LATLON_TOLERANCE_DEG = 2e-7  # MISSION_ITEM_INT stores 1e-7 degrees: one rounding step each way
RADIUS_TOLERANCE_M = 0.01  # param1 is a float32
UPLOAD_ATTEMPTS = 5  # transfers time out on a loaded machine (MAVSDK counts wall time); a refusal ends at once


def _ring(origin: frames.GeoOrigin, poly: Polygon) -> tuple[tuple[float, float], ...]:
    """A polygon's exterior in (lat, lon), without the closing repeat."""
    simple = poly.simplify(SIMPLIFY_M, preserve_topology=True)
    return tuple(frames.local_to_geodetic(origin, x, y)[:2] for x, y in list(simple.exterior.coords)[:-1])


def _grown_polygon(o: Obstacle, standoff_m: float) -> Polygon:
    """A polygon obstacle's exclusion in ENU metres (the footprint grown, ``standoff_m`` inside its keep-out)."""
    grow = exclusion_margin_m(o, standoff_m)
    if grow <= 0.0:
        return o.footprint
    return o.footprint.buffer(grow, quad_segs=max(2, int(grow / FENCE_VERTEX_SPACING_M)))


def exclusion_zone(origin: frames.GeoOrigin, o: Obstacle, standoff_m: float) -> GeoFenceZone:
    """One static obstacle as an exclusion circle or polygon, ``standoff_m`` inside its keep-out."""
    if o.is_circle:
        lat, lon, _ = frames.local_to_geodetic(origin, *o.center)
        radius_m = o.size_m + exclusion_margin_m(o, standoff_m)
        return GeoFenceZone(inclusion=False, center_deg=(lat, lon), radius_m=radius_m)
    return GeoFenceZone(inclusion=False, vertices_deg=_ring(origin, _grown_polygon(o, standoff_m)))


def mission_fence(mission: Mission) -> tuple[GeoFenceZone, ...]:
    """The inclusion zone (area + geofence margin) first, then one exclusion per static obstacle,
    in ``mission.world.static_obstacles`` order."""
    origin, world = mission.origin, mission.world
    standoff = fence_standoff_m(mission)
    area = GeoFenceZone(inclusion=True, vertices_deg=_ring(origin, world.geofence))
    return (area,) + tuple(exclusion_zone(origin, o, standoff) for o in world.static_obstacles)


class FenceGeometry:
    """The uploaded fence in the mission's ENU metres (the zones :func:`mission_fence` uploads,
    before their conversion to degrees)."""

    def __init__(self, mission: Mission):
        standoff = fence_standoff_m(mission)
        self.area = mission.world.geofence
        self.exclusions = [(o.id, _grown_polygon(o, standoff) if not o.is_circle
                            else Point(o.center).buffer(o.size_m + exclusion_margin_m(o, standoff), quad_segs=64))
                           for o in mission.world.static_obstacles]

    def breach(self, x_east_m: float, y_north_m: float, within_m: float) -> str | None:
        """Why (x, y) is at the fence (outside the inclusion or inside an exclusion, or within
        ``within_m`` of doing so), or None."""
        p = Point(x_east_m, y_north_m)
        edge = self.area.exterior.distance(p)
        if not self.area.contains(p) or edge <= within_m:
            return f"{edge:.1f} m {'inside' if self.area.contains(p) else 'outside'} the inclusion fence (the area)"
        for name, zone in self.exclusions:
            d = zone.distance(p)
            if d <= within_m:
                return (f"inside the exclusion fence of obstacle {name!r}" if d == 0.0
                        else f"{d:.1f} m from the exclusion fence of obstacle {name!r}")
        return None


def _kind(z: GeoFenceZone) -> str:
    return ("inclusion " if z.inclusion else "exclusion ") + ("circle" if z.is_circle else "polygon")


def _zone_differs(a: GeoFenceZone, b: GeoFenceZone) -> str | None:
    if a.inclusion != b.inclusion or a.is_circle != b.is_circle:
        return f"an {_kind(b)}, uploaded an {_kind(a)}"
    if a.is_circle:
        assert a.center_deg is not None and b.center_deg is not None
        if (max(abs(p - q) for p, q in zip(a.center_deg, b.center_deg)) > LATLON_TOLERANCE_DEG
                or abs(a.radius_m - b.radius_m) > RADIUS_TOLERANCE_M):
            return (f"a circle at ({b.center_deg[0]:.7f}, {b.center_deg[1]:.7f}) of {b.radius_m:g} m, uploaded "
                    f"({a.center_deg[0]:.7f}, {a.center_deg[1]:.7f}) of {a.radius_m:g} m")
        return None
    if len(a.vertices_deg) != len(b.vertices_deg):
        return f"{len(b.vertices_deg)} vertices, uploaded {len(a.vertices_deg)}"
    for k, (p, q) in enumerate(zip(a.vertices_deg, b.vertices_deg)):
        if max(abs(p[0] - q[0]), abs(p[1] - q[1])) > LATLON_TOLERANCE_DEG:
            return f"vertex {k} at ({q[0]:.7f}, {q[1]:.7f}), uploaded ({p[0]:.7f}, {p[1]:.7f})"
    return None


def verify_fence_readback(vehicle: str, sent: Sequence[GeoFenceZone], got: Sequence[GeoFenceZone]) -> None:
    """Raise GeofenceRefused unless the downloaded fence is the uploaded one."""
    if len(sent) != len(got):
        raise GeofenceRefused(f"the geofence read back has {len(got)} zones, uploaded {len(sent)}", vehicle=vehicle)
    for i, (a, b) in enumerate(zip(sent, got)):
        why = _zone_differs(a, b)
        if why is not None:
            raise GeofenceRefused(f"geofence zone {i} read back as {why}", vehicle=vehicle)


async def upload_and_verify_fence(vehicle: Vehicle, plan: "FlightPlan", report: Callable[[str], None]) -> None:
    """Upload the plan's geofence and read it back (nothing to do with ``plan.geofence`` off).

    A transfer that fails is tried again (a lossy link); one that keeps failing, or a read-back
    that differs, raises GeofenceRefused: the flight must not start.
    """
    if not plan.geofence:
        return
    zones = mission_fence(plan.mission)
    for attempt in range(1, UPLOAD_ATTEMPTS + 1):
        try:
            await vehicle.upload_fence(zones)
            got = await vehicle.download_fence()
            break
        except (MissionUploadError, CommandRefused) as exc:  # CommandRefused: MAVSDK timed out
            if attempt == UPLOAD_ATTEMPTS or (isinstance(exc, CommandRefused) and not exc.retryable):
                raise GeofenceRefused(f"{exc.message} (is the geofence supported? --no-fence skips it)",
                                      vehicle=vehicle.name) from None
            report(f"{vehicle.name}: geofence transfer failed ({exc.message}), retry {attempt}/{UPLOAD_ATTEMPTS - 1}")
            await asyncio.sleep(0.5 * attempt)
    verify_fence_readback(vehicle.name, zones, got)
    items = sum(1 if z.is_circle else len(z.vertices_deg) for z in zones)
    n = len(zones) - 1
    report(f"{vehicle.name}: geofence uploaded and read back (the area and {n} obstacle{'s' * (n != 1)}, "
           f"{items} items)")
    for line in fence_warnings(plan.mission):
        report(f"{vehicle.name}: fence: {line}")

