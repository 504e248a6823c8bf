"""Obstacle knowledge per tick: the world's obstacles prepared once as arrays, and a snapshot of
what is known now made cheaply from it, identically for the headless runner and the live companion:

    field = ObstacleField.from_world(mission.world)       # static geometry, prepared once
    snapshot = field.at_time(t_s)                         # headless: true state, now
    snapshot = field.from_tracks(adsb_tracks)             # live: what ADSB says, now

Either way the snapshot holds the obstacles' *current* position and velocity, and BDWA predicts
them at constant velocity, so the live and headless planners see exactly the same thing.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from companion.planning.dwa import ObstacleSnapshot
from companion.planning.dwa.snapshot import assemble
from uav_model.world import Obstacle, World


class ObstacleTrack(NamedTuple):
    """A moving obstacle as a sensor reports it (e.g. one ADSB_VEHICLE): centre and velocity."""

    id: str
    x_m: float
    y_m: float
    vx_m_s: float
    vy_m_s: float


@dataclass(frozen=True, eq=False)
class ObstacleField:
    """The world's obstacles prepared once as arrays; makes a snapshot per tick cheaply.

    Static obstacles are fixed. Moving ones keep their shape, which a track places at its
    reported centre. A track whose id the mission does not know is an unknown intruder: it is
    avoided as a disc of ``unknown_radius_m`` (true size, plus the mission's inflation ratio).
    """

    static: ObstacleSnapshot
    moving: dict[str, Obstacle] = field(repr=False)
    inflation_ratio: float
    unknown_radius_m: float

    @classmethod
    def from_world(cls, world: World, *, inflation_ratio: float | None = None,
                   unknown_radius_m: float = 150.0) -> "ObstacleField":
        circles: list = []
        polygons: list = []
        for o in world.static_obstacles:
            _shape_rows(o, o.center, (0.0, 0.0), circles, polygons)
        if inflation_ratio is None:  # the ratio every obstacle of the mission was built with
            ratios = [o.margin_m / o.size_m for o in world.obstacles if o.size_m > 0]
            inflation_ratio = ratios[0] if ratios else 0.2
        return cls(ObstacleSnapshot.build(circles, polygons), {o.id: o for o in world.moving_obstacles},
                   inflation_ratio, unknown_radius_m)

    def from_tracks(self, tracks: Iterable[ObstacleTrack | tuple]) -> ObstacleSnapshot:
        """Snapshot from the static world plus moving obstacles' (id, x, y, vx, vy) now."""
        circles: list = []
        polygons: list = []
        for track in tracks:
            oid, x, y, vx, vy = track
            shape = self.moving.get(oid)
            if shape is None:
                r = self.unknown_radius_m
                circles.append((oid, float(x), float(y), r, r * self.inflation_ratio, float(vx), float(vy)))
            else:
                _shape_rows(shape, (float(x), float(y)), (float(vx), float(vy)), circles, polygons)
        if not circles and not polygons:
            return self.static
        return self.static.merged(ObstacleSnapshot.build(circles, polygons))

    def tracks_at(self, t_s: float) -> list[ObstacleTrack]:
        """The true state of every moving obstacle at ``t_s`` (what a perfect ADSB would say)."""
        out = []
        for o in self.moving.values():
            x, y = o.center_at(t_s)
            vx, vy = o.motion.velocity_at(t_s)
            out.append(ObstacleTrack(o.id, x, y, vx, vy))
        return out

    def at_time(self, t_s: float) -> ObstacleSnapshot:
        """Headless snapshot: moving obstacles' true position and velocity at ``t_s``."""
        return self.from_tracks(self.tracks_at(t_s))

    def at_times(self, times_s: np.ndarray) -> Iterator[ObstacleSnapshot]:
        """``at_time(t)`` for every t of ``times_s``, made cheaply: the headless runner knows
        every tick time up front. Every snapshot is a template (static + moving obstacles at
        their reference position, built once) with only the moving rows changed: their
        positions for all times come from one vectorised ``offset_at`` call per obstacle, added
        to the template in bulk, and each snapshot views its row of those arrays."""
        times = np.asarray(times_s, dtype=float)
        moving = list(self.moving.values())
        if not moving:
            yield from (self.static for _ in times)
            return
        template = self.from_tracks([ObstacleTrack(o.id, o.center[0], o.center[1], 0.0, 0.0) for o in moving])
        n_sc, n_sp = len(self.static.circle_ids), len(self.static.poly_ids)
        n_c = len(template.circle_ids)
        rows = []  # (obstacle, is circle, row in its kind's arrays, row among all obstacles)
        k_c = k_p = 0
        for o in moving:
            row = n_sc + k_c if o.is_circle else n_sp + k_p
            rows.append((o, o.is_circle, row, row if o.is_circle else n_c + row))
            k_c, k_p = k_c + o.is_circle, k_p + (not o.is_circle)
        placed = ("circle_xy_m", "bound_xy_m") + (("poly_a_m", "poly_b_m", "poly_centre_m") if k_p else ())
        bulk = {name: np.repeat(getattr(template, name)[None], len(times), axis=0) for name in placed}
        for o, circle, row, bound in rows:
            off = o.offset_at(times)  # (T, 2)
            bulk["bound_xy_m"][:, bound] += off
            if circle:
                bulk["circle_xy_m"][:, row] += off
            else:
                bulk["poly_a_m"][:, row] += off[:, None, :]
                bulk["poly_b_m"][:, row] += off[:, None, :]
                bulk["poly_centre_m"][:, row] += off
        fields = {name: getattr(template, name) for name in _SNAPSHOT_FIELDS}
        moving_rows = np.zeros(template.count, dtype=bool)  # circles, then polygons
        for _, _, _, bound in rows:
            moving_rows[bound] = True
        moved = placed + ("circle_vel_m_s", "speed_m_s") + (("poly_vel_m_s",) if k_p else ())
        shared = (moving_rows, frozenset(moved), {})  # every snapshot below differs from the template only here
        for k in range(len(times)):
            t = float(times[k])
            values = dict(fields, _subsets={}, _shared=shared)
            for name in placed:
                values[name] = bulk[name][k]
            circle_vel = values["circle_vel_m_s"] = fields["circle_vel_m_s"].copy()
            speed = values["speed_m_s"] = fields["speed_m_s"].copy()
            if k_p:
                poly_vel = values["poly_vel_m_s"] = fields["poly_vel_m_s"].copy()
            for o, circle, row, bound in rows:
                vx, vy = o.motion.velocity_at(t)
                speed[bound] = math.hypot(vx, vy)
                vel = circle_vel if circle else poly_vel
                vel[row, 0] = vx  # two scalar stores: a tuple is converted to an array first
                vel[row, 1] = vy
            if k_p:
                values["polygons_move"] = bool(np.any(poly_vel))
            yield assemble(values)


def _shape_rows(o: Obstacle, centre: tuple[float, float], vel: tuple[float, float],
                circles: list, polygons: list) -> None:
    """Append ``o`` placed with its reference centre at ``centre`` to the snapshot rows."""
    if o.is_circle:
        circles.append((o.id, centre[0], centre[1], o.size_m, o.margin_m, vel[0], vel[1]))
    else:
        shift = np.array([centre[0] - o.center[0], centre[1] - o.center[1]])
        polygons.append((o.id, o.vertices() + shift, o.margin_m, vel[0], vel[1]))


def snapshot_from_tracks(world: World, tracks: Iterable[ObstacleTrack | tuple]) -> ObstacleSnapshot:
    """One-off snapshot from the static world and tracks; keep an ObstacleField when ticking."""
    return ObstacleField.from_world(world).from_tracks(tracks)


def snapshot_at(world: World, t_s: float) -> ObstacleSnapshot:
    """One-off headless snapshot at ``t_s``; keep an ObstacleField when ticking."""
    return ObstacleField.from_world(world).at_time(t_s)


# Every ObstacleSnapshot field, derived ones included (what assemble needs).
_SNAPSHOT_FIELDS = tuple(f.name for f in dataclasses.fields(ObstacleSnapshot))
