"""The assertions a scenario test makes on what the vehicles reported (mixed into :class:`Telemetry`).

Each reads the whole recording, take-off and landing included, and fails with a message that
names the vehicle, the time and the place: arrival, separation, clearance to the mission's TRUE
obstacles, geofence, the mode sequence, the mission stored on each vehicle, and an approach to
the station without circling it.
"""

from __future__ import annotations

import math
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np
import shapely

from companion.planning.metrics import TruthGeometry, arrival, inside_fence, pair_min_distance
from companion.testing.approach import Approach, default_region_m, station_approach

if TYPE_CHECKING:
    from uav_model.mission import Mission
    from companion.planning.metrics import Track
    from companion.vehicle.port import GeoWaypoint


class TelemetryAssertions:
    """SPEC §2 assertions over a recording; the host class supplies the readers declared here."""

    mission: Mission

    def track(self, name: str, since_mode: str | None = None) -> Track:
        raise NotImplementedError

    def modes(self, name: str) -> list[str]:
        raise NotImplementedError

    def mode_times(self, name: str, mode: str) -> list[float]:
        raise NotImplementedError

    def mission_on_vehicle(self, name: str) -> list[GeoWaypoint]:
        raise NotImplementedError

    @cached_property
    def _truth(self) -> TruthGeometry:
        return TruthGeometry(self.mission.world)

    @cached_property
    def _plans(self) -> dict[str | None, object]:  # variant -> FlightPlan, computed on first use
        return {}

    def assert_success(self) -> None:
        """SPEC §2: every vehicle arrived, no obstacle contact, separation and geofence kept."""
        self.assert_clearance()
        self.assert_separation()
        self.assert_geofence()
        self.assert_arrived()

    def assert_arrived(self, *names: str) -> None:
        """Each vehicle (default: all) came within the arrival radius of its goal station, within
        the time limit counted from its departure (entry into OFFBOARD)."""
        radius = self.mission.safety.arrival_radius_m
        for name in names or [v.name for v in self.mission.vehicles]:
            spec, tr = self.mission.vehicle(name), self.track(name)
            t_arrive, _, _ = arrival(tr, spec.goal_enu_m, radius)
            if t_arrive is None:
                d = np.hypot(tr.x_m - spec.goal_enu_m[0], tr.y_m - spec.goal_enu_m[1])
                k = int(np.argmin(d))
                raise AssertionError(
                    f"vehicle {name!r} never reached station {spec.goal} (within {radius:g} m): closest "
                    f"{d[k]:.1f} m at t={tr.t_s[k]:.1f} s; last position ({tr.x_m[-1]:.0f}, {tr.y_m[-1]:.0f}) m "
                    f"at t={tr.t_s[-1]:.1f} s; modes {' -> '.join(self.modes(name))}")
            departures = self.mode_times(name, "OFFBOARD")
            if departures and t_arrive - departures[0] > self.mission.safety.time_limit_s:
                raise AssertionError(f"vehicle {name!r} arrived {t_arrive - departures[0]:.1f} s after departure, "
                                     f"beyond the time limit {self.mission.safety.time_limit_s:g} s")

    def approach(self, name: str, region_m: float | None = None) -> Approach:
        """How vehicle ``name`` flew its final approach since departure (:mod:`.approach`)."""
        spec = self.mission.vehicle(name)
        radius = self.mission.safety.arrival_radius_m
        region = region_m if region_m is not None else default_region_m(spec.turn_radius_m, radius)
        return station_approach(self.track(name, "OFFBOARD"), spec.goal_enu_m, region, radius)

    def assert_no_circling(self, *names: str, region_m: float | None = None) -> None:
        """Each vehicle (default: all) flew into its arrival radius without circling its station:
        its course turned less than a full circle, and it flew less than twice the straight way,
        within ``region_m`` of the station (default: one turning diameter beyond the radius)."""
        for name in names or [v.name for v in self.mission.vehicles]:
            a = self.approach(name, region_m)
            if a.circling or not a.arrived:
                raise AssertionError(f"vehicle {name!r} near station {self.mission.vehicle(name).goal!r}: {a.describe()}")

    def assert_separation(self, min_m: float | None = None) -> None:
        """No two vehicles ever closer than ``min_m`` (default: the mission's), between samples too."""
        min_m = self.mission.safety.min_separation_m if min_m is None else min_m
        names = [v.name for v in self.mission.vehicles]
        tracks = {n: self.track(n) for n in names}
        for i, a in enumerate(names):
            for b in names[i + 1:]:
                ta, tb = tracks[a], tracks[b]
                lo, hi = max(ta.t_s[0], tb.t_s[0]), min(ta.t_s[-1], tb.t_s[-1])
                t = np.unique(np.concatenate([ta.t_s, tb.t_s]))
                t = t[(t >= lo) & (t <= hi)]
                if len(t) < 2:
                    continue
                (ax, ay), (bx, by) = ta.at(t), tb.at(t)
                d = pair_min_distance(ax[:-1], ay[:-1], ax[1:], ay[1:], bx[:-1], by[:-1], bx[1:], by[1:])
                k = int(np.argmin(d))
                if d[k] < min_m:
                    raise AssertionError(
                        f"vehicles {a!r} and {b!r} came within {d[k]:.1f} m of each other (minimum {min_m:g} m) "
                        f"between t={t[k]:.1f} and {t[k + 1]:.1f} s, {a} near ({ax[k]:.0f}, {ay[k]:.0f}) m, "
                        f"{b} near ({bx[k]:.0f}, {by[k]:.0f}) m")

    def assert_clearance(self, min_m: float = 0.0) -> None:
        """No vehicle ever touched a TRUE (un-inflated) obstacle footprint, static or moving, checked
        along each step's segment; with ``min_m`` > 0, it also kept that distance."""
        for v in self.mission.vehicles:
            tr = self.track(v.name)
            if len(tr) < 2:
                continue
            x0, y0, x1, y1, t0, t1 = tr.x_m[:-1], tr.y_m[:-1], tr.x_m[1:], tr.y_m[1:], tr.t_s[:-1], tr.t_s[1:]
            d = self._truth.segment_clearance_m(x0, y0, x1, y1, t0, t1)
            k = int(np.argmin(d))
            if d[k] <= 0.0 or d[k] < min_m:
                obstacle = self._nearest_obstacle(x0[k], y0[k], x1[k], y1[k], t0[k], t1[k])
                what = "entered" if d[k] <= 0.0 else f"came within {d[k]:.1f} m (minimum {min_m:g} m) of"
                raise AssertionError(
                    f"vehicle {v.name!r} {what} obstacle {obstacle!r} (true footprint) between t={t0[k]:.1f} and "
                    f"{t1[k]:.1f} s, from ({x0[k]:.0f}, {y0[k]:.0f}) to ({x1[k]:.0f}, {y1[k]:.0f}) m")

    def _nearest_obstacle(self, x0, y0, x1, y1, t0, t1) -> str:
        best, best_id = math.inf, "?"
        for o in self.mission.world.obstacles:
            (dx0, dy0), (dx1, dy1) = o.offset_at(t0), o.offset_at(t1)
            seg = shapely.LineString([(x0 - dx0, y0 - dy0), (x1 - dx1, y1 - dy1)])  # in the obstacle's frame
            d = seg.distance(o.footprint)
            if d < best:
                best, best_id = d, o.id
        return best_id

    def assert_geofence(self) -> None:
        """No vehicle ever left the geofence (the area plus the mission's margin)."""
        w = self.mission.world
        m = w.geofence_margin_m
        for v in self.mission.vehicles:
            tr = self.track(v.name)
            out = np.flatnonzero(~inside_fence(w, tr.x_m, tr.y_m))
            if out.size:
                k = int(out[0])
                raise AssertionError(
                    f"vehicle {v.name!r} left the geofence at t={tr.t_s[k]:.1f} s, at ({tr.x_m[k]:.0f}, "
                    f"{tr.y_m[k]:.0f}) m; fence x {w.x_min_m - m:g}..{w.x_max_m + m:g}, y {w.y_min_m - m:g}.."
                    f"{w.y_max_m + m:g} m")

    def assert_modes_in_order(self, name: str, *modes: str) -> None:
        """Vehicle ``name`` went through ``modes`` in this order (others may come in between)."""
        seen = self.modes(name)
        it = iter(seen)
        if not all(any(m == s for s in it) for m in modes):
            raise AssertionError(f"vehicle {name!r}: expected modes {' -> '.join(modes)} in this order, "
                                 f"reported {' -> '.join(seen)}")

    def assert_mission_matches_plan(self, *names: str, variant: str | None = None) -> None:
        """The mission stored on each vehicle (default: all) is the planned route, waypoint by waypoint
        (what ``companion plan`` / ``upload`` compute for the mission and ``variant``)."""
        from companion.app.flight_plan import ALT_TOLERANCE_M, LATLON_TOLERANCE_DEG, prepare

        plan = self._plans.get(variant)
        if plan is None:
            plan = self._plans[variant] = prepare(self.mission, variant)
        for name in names or [v.name for v in self.mission.vehicles]:
            expected = plan.waypoints(self.mission.vehicle(name))
            stored = self.mission_on_vehicle(name)
            if len(stored) != len(expected):
                raise AssertionError(f"vehicle {name!r} holds {len(stored)} mission items, the plan has "
                                     f"{len(expected)}")
            for i, (got, want) in enumerate(zip(stored, expected)):
                if (abs(got.lat_deg - want.lat_deg) > LATLON_TOLERANCE_DEG
                        or abs(got.lon_deg - want.lon_deg) > LATLON_TOLERANCE_DEG
                        or abs(got.alt_rel_m - want.alt_rel_m) > ALT_TOLERANCE_M):
                    raise AssertionError(
                        f"vehicle {name!r} mission item {i} is ({got.lat_deg:.7f}, {got.lon_deg:.7f}, "
                        f"{got.alt_rel_m:g} m), the plan says ({want.lat_deg:.7f}, {want.lon_deg:.7f}, "
                        f"{want.alt_rel_m:g} m)")
