"""PX4's geofence: the stored FENCE plan as geometry in the mission's ENU frame, and its breach action.

    fence_from_items(items, origin) -> Fence        pure: MISSION_ITEM_INTs -> rings / circles
    Fence.breached(x_east_m, y_north_m) -> bool     outside every inclusion, or inside an exclusion
    Geofence(vehicle).check(t) -> [Emit]            per step: a new breach takes GF_ACTION

As PX4 (navigator ``Geofence``, commander ``failsafe.cpp`` ``fromGfActParam``): a position is
inside the fence when it lies in at least one inclusion zone (if there are any) and in no exclusion
zone; a breach is reported once, as it begins (STATUSTEXT "Geofence: approaching or outside
geofence", as PX4's health checks send it), and while armed it takes GF_ACTION: 0 none,
1 warning, 2 Hold, 3 Return, 4 terminate, 5 Land (PX4's default 2). The action is not undone by the stub: a client may switch mode again
(PX4 lets the user take over a geofence Hold by a mode switch), and a new breach acts again.
GF_PREDICT 1 also checks the point PX4's navigator tests: its stopping distance ahead along the
velocity (:func:`uav_model.fence_margin.px4_braking_reach_m`; PX4's experimental trigger, default 0).
GF_MAX_HOR_DIST (> 0) is a circle around home, as PX4's ("Geofence: exceeding maximum distance to
Home"), with the same action. While the vehicle is in the mode the action chose, its heartbeat
says MAV_STATE_CRITICAL, as PX4's does in any failsafe. PX4 refuses to arm while the vehicle is outside its
fence; so does the stub.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import takewhile
from typing import TYPE_CHECKING

from pymavlink.dialects.v20 import common as mavlink
from shapely.geometry import Polygon

from uav_model import frames
from uav_model.fence_margin import px4_braking_reach_m
from sim_bridge.vehicle.mission_protocol import FENCE, MissionItem
from sim_bridge.vehicle.px4 import FlightMode
from sim_bridge.vehicle.types import Emit

if TYPE_CHECKING:
    from sim_bridge.vehicle import SimVehicle

# PX4's geofenceCheck.cpp STATUSTEXT (mavlink_log_critical; "Geofence violation: ..." is its event)
BREACH_TEXT = "Geofence: approaching or outside geofence"
DISTANCE_TEXT = "Geofence: exceeding maximum distance to Home"  # GF_MAX_HOR_DIST
_VERTEX = {mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION: True,
           mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION: False}
_CIRCLE = {mavlink.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION: True, mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION: False}


class GeofenceAction(enum.IntEnum):
    """GF_ACTION, with PX4's values."""

    NONE = 0
    WARN = 1
    HOLD = 2
    RTL = 3
    TERMINATE = 4
    LAND = 5


@dataclass(frozen=True, slots=True)
class Circle:
    x_east_m: float
    y_north_m: float
    radius_m: float

    def contains(self, x: float, y: float) -> bool:
        return math.hypot(x - self.x_east_m, y - self.y_north_m) <= self.radius_m


@dataclass(frozen=True, slots=True)
class Ring:
    """A fence polygon (ENU vertices, no closing repeat). Checked every physics step, so in plain
    Python: a scalar shapely predicate costs ~50 us, this a few (bounding box first)."""

    vertices: tuple[tuple[float, float], ...]

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        xs, ys = zip(*self.vertices)
        return min(xs), min(ys), max(xs), max(ys)

    @property
    def polygon(self) -> Polygon:
        return Polygon(self.vertices)

    def contains(self, x: float, y: float) -> bool:
        """Even-odd ray casting (a point exactly on an edge may fall either way)."""
        inside = False
        vs = self.vertices
        x1, y1 = vs[-1]
        for x2, y2 in vs:
            if (y1 > y) != (y2 > y) and x < x1 + (y - y1) * (x2 - x1) / (y2 - y1):
                inside = not inside
            x1, y1 = x2, y2
        return inside


@dataclass(frozen=True)
class Fence:
    """Inclusion and exclusion zones in mission ENU metres."""

    inclusion_polygons: tuple[Ring, ...] = ()
    exclusion_polygons: tuple[Ring, ...] = ()
    inclusion_circles: tuple[Circle, ...] = ()
    exclusion_circles: tuple[Circle, ...] = ()
    empty: bool = field(default=True, init=False)
    _boxes: tuple[tuple[float, float, float, float], ...] = field(default=(), init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_boxes", tuple(r.bounds for r in self.exclusion_polygons))
        object.__setattr__(self, "empty", not (self.inclusion_polygons or self.exclusion_polygons
                                               or self.inclusion_circles or self.exclusion_circles))

    def breached(self, x_east_m: float, y_north_m: float) -> bool:
        x, y = x_east_m, y_north_m
        if self.inclusion_polygons or self.inclusion_circles:
            for zone in self.inclusion_polygons + self.inclusion_circles:
                if zone.contains(x, y):
                    break
            else:
                return True
        for (x0, y0, x1, y1), r in zip(self._boxes, self.exclusion_polygons):
            if x0 <= x <= x1 and y0 <= y <= y1 and r.contains(x, y):
                return True
        for c in self.exclusion_circles:
            if c.radius_m > 0.0 and c.contains(x, y):
                return True
        return False


def fence_from_items(items: Sequence[MissionItem], origin: frames.GeoOrigin) -> Fence:
    """The zones a FENCE plan describes. A polygon is ``param1`` consecutive vertex items of one
    kind (the mission protocol refuses fewer than 3); an incomplete one is ignored."""
    polys: dict[bool, list[Ring]] = {True: [], False: []}
    circles: dict[bool, list[Circle]] = {True: [], False: []}
    i = 0
    while i < len(items):
        it = items[i]
        x, y, _ = frames.geodetic_to_local(origin, it.lat_deg, it.lon_deg)
        if it.command in _CIRCLE:
            circles[_CIRCLE[it.command]].append(Circle(x, y, float(it.param1)))
            i += 1
            continue
        if it.command not in _VERTEX:  # the return point
            i += 1
            continue
        n = max(int(it.param1), 1)
        run = list(takewhile(lambda r: r.command == it.command, items[i:i + n]))
        if n >= 3 and len(run) == n:
            ring = [frames.geodetic_to_local(origin, r.lat_deg, r.lon_deg)[:2] for r in run]
            polys[_VERTEX[it.command]].append(Ring(tuple(ring)))
        i += len(run)
    return Fence(tuple(polys[True]), tuple(polys[False]), tuple(circles[True]), tuple(circles[False]))


class Geofence:
    """The vehicle's geofence: rebuilt when the FENCE plan changes, checked every step."""

    def __init__(self, v: "SimVehicle"):
        self._v = v
        self._items: tuple[MissionItem, ...] = ()
        self.fence = Fence()
        self.breached = False
        self.breaches: list[tuple[float, GeofenceAction]] = []  # (sim time, action taken), for tests
        self.action_mode: FlightMode | None = None  # the mode GF_ACTION entered (a failsafe while it lasts)

    @property
    def action(self) -> GeofenceAction:
        return GeofenceAction(int(self._v.params["GF_ACTION"]))

    def outside(self) -> bool:
        """Whether the vehicle is outside its fence now (or, with GF_PREDICT, will be once it brakes)."""
        return self.violation() is not None

    def violation(self) -> str | None:
        """PX4's words for the fence the vehicle is outside of now, or None when inside all."""
        v = self._v
        items = v.missions.plan(FENCE)
        if items is not self._items:
            self._items = items
            self.fence = fence_from_items(items, v.origin)
        if v.params["GF_ACTION"] == GeofenceAction.NONE:
            return None
        s = v.state
        points = [(s.north_m, s.east_m)]
        if v.params["GF_PREDICT"] >= 1 and s.ground_speed_m_s > 1e-3:
            k = px4_braking_reach_m(s.ground_speed_m_s, v.params["MPC_ACC_HOR"], v.params["MPC_ACC_HOR_MAX"],
                                    v.params["MPC_JERK_AUTO"]) / s.ground_speed_m_s
            points.append((s.north_m + s.vn_m_s * k, s.east_m + s.ve_m_s * k))
        max_dist = float(v.params["GF_MAX_HOR_DIST"])
        home_n, home_e, _ = v.home_ned
        if max_dist > 0.0 and any(math.hypot(n - home_n, e - home_e) > max_dist for n, e in points):
            return DISTANCE_TEXT
        if not self.fence.empty and any(self.fence.breached(e, n) for n, e in points):
            return BREACH_TEXT
        return None

    def check(self, t: float) -> list[Emit]:
        """One step: on a new breach, say so and (armed) take GF_ACTION."""
        if self.action_mode is not None and self._v.mode is not self.action_mode:
            self.action_mode = None  # the client took over (or the action ended): the failsafe is over
        text = self.violation()
        started = text is not None and not self.breached
        self.breached = text is not None
        if not started:
            return []
        v = self._v
        out = [Emit(v.tele.statustext(mavlink.MAV_SEVERITY_CRITICAL, text))]
        action = self.action
        if not v.armed:
            return out
        self.breaches.append((t, action))
        if action is GeofenceAction.WARN:
            return out
        out.append(Emit(v.tele.statustext(mavlink.MAV_SEVERITY_CRITICAL, "Failsafe activated")))
        if action is GeofenceAction.TERMINATE:
            return out + v.modes.disarm(True, "failsafe")[1]
        target = {GeofenceAction.HOLD: FlightMode.HOLD, GeofenceAction.RTL: FlightMode.RTL,
                  GeofenceAction.LAND: FlightMode.LAND}[action]
        if target is FlightMode.RTL and not v.in_air:
            target = FlightMode.HOLD
        v.modes.enter(target)
        self.action_mode = target
        if target is FlightMode.RTL:
            out.append(Emit(v.nav.rtl_start_text()))
        return out
