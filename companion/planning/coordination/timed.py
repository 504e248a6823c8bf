"""Timed routes made: forecasts of a vehicle at cruise (after a hold, from where it was seen, or
along a flown forecast's own pace), a departure hold, and the closest approach of two plans.

    route = forecast("a", sparse_xy, speed_m_s=10.0, hold_s=75.0)   # cruise after a hold
    held(route, 30.0)                                                  # 30 s later still
    forecast_from("a", sparse_xy, (x, y), t, 10.0)                     # re-forecast where it was seen
"""

from __future__ import annotations

import numpy as np

from companion.planning.errors import PlanningError
from companion.planning.timed_route import TimedRoute


def closest_approach_m(first: TimedRoute, second: TimedRoute, step_s: float = 0.5) -> float:
    """The least planned distance between two timed routes (sampled every ``step_s``)."""
    end = max(first.t_s[-1], second.t_s[-1])
    t = np.arange(min(first.t_s[0], second.t_s[0]), end + step_s, step_s)
    return float(np.hypot(*(first.planned_position_at(t) - second.planned_position_at(t)).T).min())


def forecast(vehicle: str, route_enu_m: np.ndarray, speed_m_s: float, hold_s: float = 0.0,
             start_s: float = 0.0) -> TimedRoute:
    """A vehicle flying ``route_enu_m`` (M, 2) at constant ``speed_m_s`` after holding ``hold_s``
    at its first point (the forecast of a higher-priority vehicle)."""
    if not speed_m_s > 0:
        raise PlanningError(f"forecast of {vehicle!r}: speed must be positive, got {speed_m_s!r}")
    if not hold_s >= 0:
        raise PlanningError(f"forecast of {vehicle!r}: hold must be >= 0 s, got {hold_s!r}")
    p = np.asarray(route_enu_m, dtype=float).reshape(-1, 2)
    t = start_s + np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(p, axis=0).T))]) / speed_m_s
    return held(TimedRoute(vehicle, t, p), hold_s)


def held(route: TimedRoute, hold_s: float) -> TimedRoute:
    """``route`` delayed by a departure hold of ``hold_s`` at its first point: it still starts
    when it did, and waits there that long before going on as before."""
    if not hold_s > 0:
        return route
    return TimedRoute(route.vehicle, np.concatenate([route.t_s[:1], route.t_s + hold_s]),
                      np.vstack([route.xy_enu_m[:1], route.xy_enu_m]))


def _nearest_on(p: np.ndarray, here: np.ndarray) -> tuple[int, float, np.ndarray]:
    """The point of the polyline ``p`` (M >= 2, 2) nearest ``here``: its segment, the fraction
    along it, and the point (the first segment on ties)."""
    a, d = p[:-1], np.diff(p, axis=0)
    len2 = np.einsum("ij,ij->i", d, d)
    u = np.clip(np.einsum("ij,ij->i", here - a, d) / np.where(len2 > 0, len2, 1.0), 0.0, 1.0)
    foot = a + d * u[:, None]
    i = int(np.argmin(np.hypot(*(foot - here).T)))
    return i, float(u[i]), foot[i]


def forecast_from(vehicle: str, route_enu_m: np.ndarray, xy_enu_m: tuple[float, float], t_s: float,
                  speed_m_s: float) -> TimedRoute:
    """A vehicle seen at ``xy_enu_m`` at time ``t_s`` flying the rest of ``route_enu_m`` at
    ``speed_m_s``: from its nearest point on the route (a re-forecast of a higher-priority vehicle
    that strayed from its plan)."""
    p = np.asarray(route_enu_m, dtype=float).reshape(-1, 2)
    here = np.asarray(xy_enu_m, dtype=float)
    if len(p) < 2:
        return forecast(vehicle, np.vstack([here, p]), speed_m_s, start_s=t_s)
    i, _, foot = _nearest_on(p, here)
    rest = np.vstack([here, foot, p[i + 1:]])
    return forecast(vehicle, rest, speed_m_s, start_s=t_s)


def forecast_along(route: TimedRoute, xy_enu_m: tuple[float, float], t_s: float, speed_m_s: float) -> TimedRoute:
    """A vehicle seen at ``xy_enu_m`` at time ``t_s`` going on as its timed ``route`` has it fly:
    to the route's nearest point at ``speed_m_s``, then the rest at the route's own pace, shifted
    to begin when it gets there. For a flown forecast (:mod:`companion.planning.flight.forecast`) that keeps its
    slower corners and final approach, which :func:`forecast_from` would fly at cruise. Waits
    are left out (only their last instant is kept): a vehicle seen once it left does not wait
    again."""
    keep = np.ones(len(route.t_s), dtype=bool)
    keep[:-1] = np.any(route.xy_enu_m[1:] != route.xy_enu_m[:-1], axis=1)
    p, t = route.xy_enu_m[keep], route.t_s[keep]
    here = np.asarray(xy_enu_m, dtype=float)
    if len(p) < 2:
        return forecast(route.vehicle, np.vstack([here, p]), speed_m_s, start_s=t_s)
    i, u, foot = _nearest_on(p, here)
    at_foot = t_s + float(np.hypot(*(foot - here))) / speed_m_s
    shift = at_foot - (t[i] + u * (t[i + 1] - t[i]))
    return TimedRoute(route.vehicle, np.concatenate([[t_s, at_foot], t[i + 1:] + shift]),
                      np.vstack([here, foot, p[i + 1:]]))
