"""ObstacleSnapshot: the obstacles known now packed as arrays for the vectorised critics, with
merging (static + moving) and culling to what a rollout can reach."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from companion.planning.dwa.geometry import one_layout, to_segment


@dataclass(frozen=True, eq=False)
class ObstacleSnapshot:
    """Obstacles as known now, as arrays (ENU m, m/s), ready for the vectorised critics.

    Circles are exact (centre + true radius + margin). Every other shape is its true polygon:
    edge e of polygon p runs from ``poly_a_m[p, e]`` to ``poly_b_m[p, e]``.
    Polygons with fewer edges than the largest are padded with zero-length edges at their first
    vertex, which change neither a distance nor a crossing count, so that every reduction over
    a polygon's edges is one reduction over axis 1. The inflated shape is "true shape + margin"
    (the round-joined buffer the world uses), so the clearance to it is the distance to the true
    edges minus the margin. Each obstacle carries the velocity it is predicted with (zero when
    static). Build with :meth:`build`.
    """

    circle_ids: tuple[str, ...]
    circle_xy_m: np.ndarray  # (C, 2)
    circle_radius_m: np.ndarray  # (C,) true radius
    circle_margin_m: np.ndarray  # (C,)
    circle_vel_m_s: np.ndarray  # (C, 2)
    poly_ids: tuple[str, ...]
    poly_a_m: np.ndarray  # (P, E, 2) edge start points = the polygon's vertices (padded)
    poly_b_m: np.ndarray  # (P, E, 2) edge end points (= start for padding)
    poly_margin_m: np.ndarray  # (P,)
    poly_centre_m: np.ndarray  # (P, 2) a point and a radius that bound each true polygon
    poly_bound_m: np.ndarray  # (P,)
    poly_vel_m_s: np.ndarray  # (P, 2)

    # Derived once per snapshot. Per obstacle (circles, then polygons): a disc bounding the
    # inflated shape, and its speed. Per edge: 1/length^2 and dx/dy (point-in-polygon test).
    bound_xy_m: np.ndarray = field(init=False, repr=False)
    bound_radius_m: np.ndarray = field(init=False, repr=False)
    speed_m_s: np.ndarray = field(init=False, repr=False)
    poly_d_m: np.ndarray = field(init=False, repr=False)  # (P, E, 2) edge vectors
    poly_inv_len2: np.ndarray = field(init=False, repr=False)
    poly_dx_per_dy: np.ndarray = field(init=False, repr=False)
    polygons_move: bool = field(init=False, repr=False)
    _subsets: dict = field(init=False, repr=False)  # near() results by keep-mask: a cache
    # (rows that move, names of the fields that differ, cache) shared by snapshots that differ
    # only in those rows and fields (the headless runner's per-tick snapshots: the moving
    # obstacles translated). _take then builds a subset of unmoved obstacles once for all of
    # them, and otherwise indexes only the fields that differ. None: not shared.
    _shared: tuple[np.ndarray, frozenset, dict] | None = field(init=False, repr=False)

    def __post_init__(self) -> None:
        def put(name, value):
            object.__setattr__(self, name, value)
        put("bound_xy_m", np.concatenate([self.circle_xy_m, self.poly_centre_m]))
        put("bound_radius_m", np.concatenate([self.circle_radius_m + self.circle_margin_m,
                                              self.poly_bound_m + self.poly_margin_m]))
        vel = np.concatenate([self.circle_vel_m_s, self.poly_vel_m_s])
        put("speed_m_s", np.hypot(vel[:, 0], vel[:, 1]))
        put("poly_d_m", self.poly_b_m - self.poly_a_m)
        dx, dy = self.poly_d_m[..., 0], self.poly_d_m[..., 1]
        put("poly_inv_len2", 1.0 / np.maximum(dx * dx + dy * dy, 1e-12))
        put("poly_dx_per_dy", dx / np.where(dy == 0.0, 1.0, dy))
        put("polygons_move", bool(np.any(self.poly_vel_m_s)))
        put("_subsets", {})
        put("_shared", None)

    @property
    def count(self) -> int:
        return len(self.circle_ids) + len(self.poly_ids)

    @property
    def ids(self) -> tuple[str, ...]:
        return self.circle_ids + self.poly_ids

    def vertices(self, i: int) -> np.ndarray:
        """The true vertices (N, 2) of polygon i, without padding."""
        n = int(np.count_nonzero(np.any(self.poly_d_m[i] != 0.0, axis=1)))
        return self.poly_a_m[i, :n]

    @staticmethod
    def build(circles: list[tuple[str, float, float, float, float, float, float]],
              polygons: list[tuple[str, np.ndarray, float, float, float]]) -> "ObstacleSnapshot":
        """``circles``: (id, x, y, radius, margin, vx, vy); ``polygons``: (id, vertices (N, 2)
        without the closing repeat, margin, vx, vy); all at the current time."""
        c = np.asarray([row[1:] for row in circles], dtype=float).reshape(-1, 6)
        verts = [np.asarray(row[1], dtype=float) for row in polygons]
        edges = max((len(v) for v in verts), default=0)
        a = np.zeros((len(verts), edges, 2))
        b = np.zeros((len(verts), edges, 2))
        for i, v in enumerate(verts):
            a[i, :len(v)] = v
            a[i, len(v):] = v[0]
            b[i] = a[i]
            b[i, :len(v)] = np.roll(v, -1, axis=0)
        centres = np.asarray([v.mean(axis=0) for v in verts]).reshape(-1, 2)
        return ObstacleSnapshot(
            circle_ids=tuple(str(row[0]) for row in circles),
            circle_xy_m=c[:, 0:2].copy(), circle_radius_m=c[:, 2].copy(),
            circle_margin_m=c[:, 3].copy(), circle_vel_m_s=c[:, 4:6].copy(),
            poly_ids=tuple(str(row[0]) for row in polygons), poly_a_m=a, poly_b_m=b,
            poly_margin_m=np.asarray([row[2] for row in polygons], dtype=float),
            poly_centre_m=centres,
            poly_bound_m=np.asarray([np.hypot(*(v - m).T).max() for v, m in zip(verts, centres)], dtype=float),
            poly_vel_m_s=np.asarray([row[3:5] for row in polygons], dtype=float).reshape(-1, 2),
        )

    def merged(self, other: "ObstacleSnapshot") -> "ObstacleSnapshot":
        """Both snapshots' obstacles in one (e.g. prepared static ones + this tick's moving ones).
        The derived arrays are joined too, not derived again: this runs every tick."""
        if not other.count:
            return self
        if not self.count:
            return other
        edges = max(self.poly_a_m.shape[1], other.poly_a_m.shape[1])
        cat = np.concatenate
        values = {"circle_ids": self.circle_ids + other.circle_ids, "poly_ids": self.poly_ids + other.poly_ids,
                  "polygons_move": self.polygons_move or other.polygons_move, "_subsets": {}, "_shared": None}
        for name in ("circle_xy_m", "circle_radius_m", "circle_margin_m", "circle_vel_m_s", "poly_margin_m",
                     "poly_centre_m", "poly_bound_m", "poly_vel_m_s"):
            values[name] = cat([getattr(self, name), getattr(other, name)])
        n1, n2 = len(self.circle_ids), len(other.circle_ids)
        for name in ("bound_xy_m", "bound_radius_m", "speed_m_s"):  # circles first, then polygons
            a, b = getattr(self, name), getattr(other, name)
            values[name] = cat([a[:n1], b[:n2], a[n1:], b[n2:]])
        values["poly_a_m"] = cat([_pad_edges(self.poly_a_m, edges), _pad_edges(other.poly_a_m, edges)])
        values["poly_b_m"] = cat([_pad_edges(self.poly_b_m, edges, self.poly_a_m),
                                  _pad_edges(other.poly_b_m, edges, other.poly_a_m)])
        values["poly_d_m"] = cat([_pad_edges(self.poly_d_m, edges, zeros=True),
                                  _pad_edges(other.poly_d_m, edges, zeros=True)])
        for name, fill in (("poly_inv_len2", 1e12), ("poly_dx_per_dy", 0.0)):  # what a zero-length edge gets
            a, b = getattr(self, name), getattr(other, name)
            values[name] = cat([_pad_columns(a, edges, fill), _pad_columns(b, edges, fill)])
        return assemble(values)

    def near(self, x_m: float, y_m: float, reach_m: float, horizon_s: float,
             to_xy: tuple[float, float] | None = None) -> "ObstacleSnapshot":
        """Only the obstacles whose inflated shape can come within ``reach_m`` of (x, y) during
        ``horizon_s`` at their predicted velocity; the others cannot touch any rollout. With
        ``to_xy``: within ``reach_m`` of the segment (x, y) -> to_xy (sight lines)."""
        return self.subset(*self.near_mask(x_m, y_m, reach_m, horizon_s, to_xy))

    def subset(self, keep: np.ndarray, kept: int) -> "ObstacleSnapshot":
        """The obstacles where ``keep`` (circles, then polygons; ``kept`` of them) is true,
        cached by mask: a culling's result (:meth:`near_mask`) as a snapshot."""
        if kept == len(keep):
            return self
        if not kept:
            return NO_OBSTACLES
        key = keep.tobytes()
        cached = self._subsets.get(key)
        if cached is None:
            cached = self._subsets[key] = self._take(keep, key)
        return cached

    def near_mask(self, x_m: float, y_m: float, reach_m: float, horizon_s: float,
                  to_xy: tuple[float, float] | None = None) -> tuple[np.ndarray, int]:
        """What :meth:`near` keeps, as a mask over the obstacles (circles, then polygons), and
        how many it keeps; for a caller that only indexes a few arrays. The compiled twin is
        :func:`.geometry_jit.near_mask`."""
        bx, by = self.bound_xy_m[:, 0], self.bound_xy_m[:, 1]
        if to_xy is None:
            dx, dy = bx - x_m, by - y_m
            d = np.sqrt(dx * dx + dy * dy)
        else:
            d = to_segment(bx, by, x_m, y_m, to_xy)
        keep = d - self.bound_radius_m - self.speed_m_s * horizon_s <= reach_m
        return keep, int(np.count_nonzero(keep))

    def arrays(self) -> tuple[np.ndarray, ...]:
        """The arrays the compiled kernels read, as one plain tuple in :data:`ARRAY_FIELDS`' order,
        each C-contiguous and writable (one compiled signature per layout: see
        :func:`.geometry.one_layout`); made once per snapshot."""
        cached = self._subsets.get(_ARRAYS)
        if cached is None:
            shared = None if self._shared is None else self._shared[2].get(_ARRAYS)
            if shared is None:
                values = [getattr(self, name) for name in ARRAY_FIELDS]
                if values[4].ndim != 3:  # no polygons at all: the shapes of the one signature
                    values[4:9] = [np.zeros((0, 0, 2))] * 3 + [np.zeros((0, 0))] * 2
                cached = tuple(one_layout(v) for v in values)
                if self._shared is not None:  # what does not move, laid out once for every snapshot sharing it
                    moved = self._shared[1]
                    self._shared[2][_ARRAYS] = (cached, [(i, name) for i, name in enumerate(ARRAY_FIELDS)
                                                         if name in moved])
            else:
                fixed, moved = shared
                values = list(fixed)
                for i, name in moved:
                    values[i] = one_layout(getattr(self, name))
                cached = tuple(values)
            self._subsets[_ARRAYS] = cached
        return cached

    def _take(self, keep: np.ndarray, key: bytes) -> "ObstacleSnapshot":
        """The obstacles where ``keep`` (circles, then polygons) is true; ``key`` is
        ``keep.tobytes()``. Indexes the derived arrays too instead of deriving them again: this
        runs every tick for fresh snapshots."""
        n_c = len(self.circle_ids)
        kc, kp = keep[:n_c], keep[n_c:]

        def pick(names) -> dict:
            return {name: getattr(self, name)[keep if rows is _BOTH else kc if rows is _CIRCLE else kp]
                    for name, rows in _ROW_FIELDS.items() if name in names}

        def ids() -> dict:
            return {"circle_ids": tuple(i for i, k in zip(self.circle_ids, kc) if k),
                    "poly_ids": tuple(i for i, k in zip(self.poly_ids, kp) if k), "_subsets": {}, "_shared": None}

        def subset(values: dict) -> "ObstacleSnapshot":
            # a cache of its own: ``values`` may come from a cache entry that other subsets share
            return assemble({**values, "_subsets": {}, "polygons_move": bool(values["poly_vel_m_s"].any())})

        if self._shared is None:
            return subset({**pick(_ROW_FIELDS), **ids()})
        moving_rows, moving_fields, cache = self._shared
        entry = cache.get(key)
        if entry is None:
            fixed = {**pick(_ROW_FIELDS.keys() - moving_fields), **ids()}
            whole = None
            if not np.any(keep & moving_rows):  # the same subset in every snapshot that shares the cache
                whole = subset({**fixed, **pick(moving_fields)})
            entry = cache[key] = (fixed, whole)
        fixed, whole = entry
        if whole is not None:
            return whole
        return subset({**fixed, **pick(moving_fields)})


def with_turned_back(snapshot: ObstacleSnapshot, x_m: float, y_m: float,
                     among: np.ndarray | None = None) -> ObstacleSnapshot:
    """``snapshot`` plus each moving obstacle that moves away from (x, y) (within 60 deg of
    straight away) once more, at the same place, predicted with its velocity reversed: a rollout
    is legal only if it keeps clear of both. A shuttle turns back at its lane's end, and a
    sensor's (ADS-B's) velocity says nothing of when; a vehicle that may slow down (a speed
    window) otherwise trails a moving obstacle down its lane just beyond the margin at its pace
    and has no room when it turns back into it. Obstacles crossing or coming closer are left
    as they are: reversing every moving obstacle also holds vehicles off lanes they must cross,
    and costs the sight line its block at the closest approach.

    ``among``: a mask (circles, then polygons) of the only obstacles to consider, those a culling
    keeps (:meth:`ObstacleSnapshot.near_mask`): a turned-back copy has its original's bounding
    disc and speed, so the same culling keeps it exactly when it keeps the original, and a copy
    culled away changes nothing."""
    n_c = len(snapshot.circle_ids)
    speeds = snapshot.speed_m_s
    away = []  # rows of the moving obstacles that move away; a few of many, so one by one (every tick)
    # the culling keeps a few: its rows read one by one, those that do not move skipped
    for i in (speeds > 0.0 if among is None else among).nonzero()[0].tolist():
        speed = float(speeds[i])
        if not speed > 0.0:
            continue
        vx, vy = (snapshot.circle_vel_m_s[i] if i < n_c else snapshot.poly_vel_m_s[i - n_c]).tolist()
        dx, dy = float(snapshot.bound_xy_m[i, 0]) - x_m, float(snapshot.bound_xy_m[i, 1]) - y_m
        along = vx * dx + vy * dy
        if along > 0.0 and along > _AWAY_COS * speed * float(np.hypot(dx, dy)):
            away.append(i)
    if not away:
        return snapshot
    moving = np.zeros(len(snapshot.speed_m_s), dtype=bool)
    moving[away] = True
    key = _TURNED_BACK + moving.tobytes()  # both vehicles often reverse the same ones in a tick
    cached = snapshot._subsets.get(key)
    if cached is not None:
        return cached
    if moving[n_c:].any():  # a moving polygon: the general way
        circles = [(snapshot.circle_ids[i], *snapshot.circle_xy_m[i], snapshot.circle_radius_m[i],
                    snapshot.circle_margin_m[i], *(-snapshot.circle_vel_m_s[i])) for i in np.flatnonzero(moving[:n_c])]
        polygons = [(snapshot.poly_ids[i], snapshot.vertices(i), snapshot.poly_margin_m[i],
                     *(-snapshot.poly_vel_m_s[i])) for i in np.flatnonzero(moving[n_c:])]
        out = snapshot.merged(ObstacleSnapshot.build(circles, polygons))
    else:  # moving circles only: their rows once more, after the circles (this runs every tick)
        out = _circles_turned_back(snapshot, moving)
    snapshot._subsets[key] = out
    return out


def _circles_turned_back(snapshot: ObstacleSnapshot, moving: np.ndarray) -> ObstacleSnapshot:
    """:func:`with_turned_back` when only circles turn back: their rows once more, after the
    circles. What does not move between ticks (ids, radii, margins) is joined once per set of
    rows turned back and kept in the cache the headless runner's snapshots share, and so is the
    turned-back snapshots' own shared cache (their moving rows, and the reversed ones): culling
    one of them then indexes only what moves, as culling a tick's snapshot does (:meth:`_take`)."""
    n_c = len(snapshot.circle_ids)
    rows = np.flatnonzero(moving)
    fixed = None
    if snapshot._shared is not None:
        moving_rows, moving_fields, cache = snapshot._shared
        fixed = cache.get((_TURNED_BACK, moving.tobytes()))
        if fixed is None:
            shared = (np.concatenate([moving_rows[:n_c], np.ones(len(rows), dtype=bool), moving_rows[n_c:]]),
                      moving_fields, {})
            fixed = cache[(_TURNED_BACK, moving.tobytes())] = _turned_back_fixed(snapshot, rows, shared)
    values = {**snapshot.__dict__, **(fixed or _turned_back_fixed(snapshot, rows, None))}
    values["circle_xy_m"] = np.concatenate([snapshot.circle_xy_m, snapshot.circle_xy_m[rows]])
    values["circle_vel_m_s"] = np.concatenate([snapshot.circle_vel_m_s, -snapshot.circle_vel_m_s[rows]])
    for name in ("bound_xy_m", "speed_m_s"):
        a = getattr(snapshot, name)
        values[name] = np.concatenate([a[:n_c], a[rows], a[n_c:]])
    values["_subsets"] = {}
    return assemble(values)


def _turned_back_fixed(snapshot: ObstacleSnapshot, rows: np.ndarray, shared) -> dict:
    """The fields of :func:`_circles_turned_back` that only the circles turned back decide."""
    n_c = len(snapshot.circle_ids)
    values = {"_shared": shared, "circle_ids": snapshot.circle_ids + tuple(snapshot.circle_ids[i] for i in rows)}
    for name in ("circle_radius_m", "circle_margin_m"):
        values[name] = np.concatenate([getattr(snapshot, name), getattr(snapshot, name)[rows]])
    a = snapshot.bound_radius_m
    values["bound_radius_m"] = np.concatenate([a[:n_c], a[rows], a[n_c:]])
    return values


# ObstacleSnapshot.arrays: circles (centre, velocity, true radius, margin), then polygons (edge
# starts, ends, vectors, 1 / length^2, dx / dy; velocity, margin, bounding centre and radius).
ARRAY_FIELDS = ("circle_xy_m", "circle_vel_m_s", "circle_radius_m", "circle_margin_m", "poly_a_m", "poly_b_m",
                "poly_d_m", "poly_inv_len2", "poly_dx_per_dy", "poly_vel_m_s", "poly_margin_m", "poly_centre_m",
                "poly_bound_m")
_ARRAYS = "arrays"  # ObstacleSnapshot.arrays' key in a snapshot's cache (the masks' keys are bytes)


class Culled(NamedTuple):
    """The obstacles of ``snapshot`` a culling keeps: a mask (circles, then polygons) and how
    many; :meth:`subset` as a snapshot, built (and cached) only when read."""

    snapshot: ObstacleSnapshot
    keep: np.ndarray
    count: int

    def subset(self) -> ObstacleSnapshot:
        return self.snapshot.subset(self.keep, self.count)


_AWAY_COS = 0.5  # with_turned_back: an obstacle within 60 deg of moving straight away
_TURNED_BACK = b"turned back"  # with_turned_back's keys in a snapshot's cache (near's are bare masks' bytes)

# The array fields of a snapshot and the rows they have: one per circle, polygon, or obstacle
# (circles first, then polygons).
_CIRCLE, _POLYGON, _BOTH = "circle", "polygon", "both"
_ROW_FIELDS = {
    **dict.fromkeys(("circle_xy_m", "circle_radius_m", "circle_margin_m", "circle_vel_m_s"), _CIRCLE),
    **dict.fromkeys(("poly_a_m", "poly_b_m", "poly_margin_m", "poly_centre_m", "poly_bound_m", "poly_vel_m_s",
                     "poly_d_m", "poly_inv_len2", "poly_dx_per_dy"), _POLYGON),
    **dict.fromkeys(("bound_xy_m", "bound_radius_m", "speed_m_s"), _BOTH),
}


def assemble(values: dict) -> ObstacleSnapshot:
    """A snapshot from every field, derived ones included (no __post_init__). The fields go
    into the instance's __dict__ in one update (a frozen dataclass without slots), not one
    ``object.__setattr__`` each: the headless runner makes a snapshot every tick."""
    out = object.__new__(ObstacleSnapshot)
    out.__dict__.update(values)
    return out


def _pad_columns(arr: np.ndarray, edges: int, fill: float) -> np.ndarray:
    missing = edges - arr.shape[1]
    return arr if missing <= 0 else np.concatenate([arr, np.full((arr.shape[0], missing), fill)], axis=1)


def _pad_edges(arr: np.ndarray, edges: int, starts: np.ndarray | None = None, zeros: bool = False) -> np.ndarray:
    """(P, E, 2) padded to ``edges`` along axis 1 with each polygon's first vertex (of
    ``starts`` when given), or with zeros: zero-length edges."""
    missing = edges - arr.shape[1]
    if missing <= 0:
        return arr
    if not len(arr) or zeros:
        return np.concatenate([arr, np.zeros((len(arr), missing, 2))], axis=1)
    first = (arr if starts is None else starts)[:, :1]
    return np.concatenate([arr, np.repeat(first, missing, axis=1)], axis=1)


NO_OBSTACLES = ObstacleSnapshot.build([], [])
