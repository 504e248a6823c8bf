"""What the companion decides before anything connects: routes, planners, the uploaded missions and fence.

:func:`prepare` is the last gate for bad input: an unreachable goal (the planner's ``NoPath``)
becomes a :class:`uav_model.mission.MissionError` naming the vehicle's ``goal`` field, so the CLI
can refuse it in one line before any vehicle is armed.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from uav_model import frames
from companion.errors import MissionUploadError
from uav_model.mission import Mission, VehicleSpec, mission_error
from companion.planning.budget import Budget, BudgetSpent
from companion.planning.coordination.certificate import OcclusionCertificate, certify
from companion.planning.coordination.plan import CoordinatedPlan, plan_coordinated
from companion.planning.errors import NoPath
from companion.planning.flight.fleet_setup import FleetSetup, build_fleet
from companion.planning.flight.forecast import first_forecast, mission_certificates
from companion.planning.timed_route import TimedRoute
from companion.planning.variants import VARIANTS, variant_needs_route, variant_nodes
from companion.vehicle.port import GeoWaypoint

from companion.planning.routes import Route, plan_routes

LATLON_TOLERANCE_DEG = 2e-7  # MISSION_ITEM_INT stores 1e-7 degrees: allow one rounding step each way
ALT_TOLERANCE_M = 0.01


@dataclass(frozen=True)
class FlightPlan:
    """A mission with its variant fixed and its routes planned, ready to upload and fly."""

    mission: Mission
    variant: str
    routes: dict[str, Route]  # empty for the station-goal variants (bdwa, dwa)
    geofence: bool = True  # upload the autopilot geofence before arming (companion.app.fence); --no-fence
    with_certificate: bool = True  # False (--no-certificate): no occlusion certificate is worked out
    certificate_budget: Budget | None = field(default=None, compare=False)  # None: as long as it takes

    @cached_property
    def certificates(self) -> tuple[OcclusionCertificate, ...]:
        """The occlusion certificate of each scored sight-line pair, the headline first (seconds
        of pure work; computed on first use), within ``certificate_budget``; empty without one (a
        single vehicle, or ``with_certificate`` off)."""
        if not self.with_certificate:
            return ()
        first = None
        if len(self.mission.vehicles) > 1 and self.mission.by_priority[0].name in self.routes:
            first = self._first_forecast(self.certificate_budget)
            if first is None:  # the forecast itself ran out of budget: nothing is decided
                return tuple(certify(self.mission, None, pair=p, budget=self.certificate_budget)
                             for p in self.mission.sight_pairs)
        return mission_certificates(self.mission, self.routes, self.certificate_budget, first=first)

    @property
    def certificate(self) -> OcclusionCertificate | None:
        """The headline certificate: the first scored pair's (:attr:`certificates`)."""
        return self.certificates[0] if self.certificates else None

    def _first_forecast(self, budget: Budget | None = None) -> TimedRoute | None:
        """The first vehicle's forecast (:func:`first_forecast`), flown once for the certificate and
        the coordinated plan alike; None when it ran out of ``budget`` (it is then flown again,
        without one, when the plan needs it)."""
        if "_first" not in self.__dict__:
            try:
                self.__dict__["_first"] = first_forecast(self.mission, self.routes, budget)  # as cached_property does
            except BudgetSpent:
                return None
        return self.__dict__["_first"]

    def certificate_advice(self) -> str | None:
        """What keeps the sight lines blocked when this plan's variant will not (a timed variant,
        the hold it needs), from the first certificate that has advice; None when there is
        nothing to say."""
        timed = tuple(n for n, v in VARIANTS.items() if v.timed)
        return next((a for c in self.certificates if (a := c.advice(self.variant, timed)) is not None), None)

    @cached_property
    def coordinated(self) -> CoordinatedPlan | None:
        """The space-time plan a timed variant flies (routes with arrival times, t = 0 at the
        common departure; the first vehicle's departure hold within ``coordination.hold_s_max``),
        or None for the other variants. Seconds of pure work on first use: the caller computes it
        before the flight (``companion run`` before its event loop), never in a worker thread
        beside the in-process fleet, whose loop it would stall."""
        if not VARIANTS[self.variant].timed or not self.routes:
            return None
        return plan_coordinated(self.mission, self.routes, self._first_forecast())

    def timed_route(self, name: str) -> TimedRoute | None:
        """The vehicle's route with arrival times (timed variants only)."""
        return None if self.coordinated is None else self.coordinated.timed.get(name)

    def fleet_setup(self) -> FleetSetup:
        """Fresh planners for every vehicle and the timed routes' clocks, built as the headless
        runner builds them (:func:`companion.planning.flight.fleet_setup.build_fleet`), on the
        coordinated plan computed before (:attr:`coordinated`)."""
        return build_fleet(self.mission, self.routes, self.variant, plan=self.coordinated)

    def nodes_enu_m(self, vehicle: VehicleSpec) -> np.ndarray:
        """The local goals the vehicle's planner follows, start first (what gets uploaded)."""
        return variant_nodes(self.variant, vehicle, self.routes.get(vehicle.name))

    def waypoints(self, vehicle: VehicleSpec) -> tuple[GeoWaypoint, ...]:
        """The route as MAVLink NAV_WAYPOINTs at the vehicle's cruise altitude above home."""
        out = []
        for x, y in self.nodes_enu_m(vehicle):
            lat, lon, _ = frames.local_to_geodetic(self.mission.origin, float(x), float(y))
            out.append(GeoWaypoint(lat_deg=lat, lon_deg=lon, alt_rel_m=vehicle.cruise_alt_m))
        return tuple(out)


def prepare(mission: Mission, variant: str | None = None) -> FlightPlan:
    """Fix the variant and plan the routes. Raises MissionError (bad variant, unreachable goal)."""
    if variant is not None:
        mission = mission.with_variant(variant)
    variant = mission.planner.variant
    routes: dict[str, Route] = {}
    if variant_needs_route(variant):
        try:
            routes = dict(plan_routes(mission))
        except NoPath as exc:
            index = next((v.index for v in mission.vehicles if v.name == exc.vehicle), None)
            field = f"vehicles[{index}].goal" if index is not None else "vehicles"
            raise mission_error(mission, field, str(exc)) from None
    return FlightPlan(mission, variant, routes)


def verify_readback(vehicle: str, sent: Sequence[GeoWaypoint], got: Sequence[GeoWaypoint]) -> None:
    """Raise MissionUploadError unless the downloaded mission is the uploaded one."""
    if len(sent) != len(got):
        raise MissionUploadError(f"read back {len(got)} waypoints, uploaded {len(sent)}", vehicle=vehicle)
    for i, (a, b) in enumerate(zip(sent, got)):
        if (abs(a.lat_deg - b.lat_deg) > LATLON_TOLERANCE_DEG or abs(a.lon_deg - b.lon_deg) > LATLON_TOLERANCE_DEG
                or abs(a.alt_rel_m - b.alt_rel_m) > ALT_TOLERANCE_M):
            raise MissionUploadError(f"waypoint {i} read back as ({b.lat_deg:.7f}, {b.lon_deg:.7f}, "
                                     f"{b.alt_rel_m:g} m), uploaded ({a.lat_deg:.7f}, {a.lon_deg:.7f}, "
                                     f"{a.alt_rel_m:g} m)", vehicle=vehicle)
