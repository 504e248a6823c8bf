"""Sparse optimisation of an A* path (paper section III.B, SPEC §1).

The general rule: walk the node list and drop the middle node of three when the segment joining
the outer two keeps clear of every inflated static obstacle (by more than ``clearance_m``). After
a drop the outer node becomes the middle one, so the walk is a greedy "string pull" from the last
kept node; the first segment that is not clear fixes the next kept node.

Obstacles are checked exactly where that is cheap and conservatively otherwise: circles by their
analytic distance (numpy, all candidate segments at once), polygons by the inflated shape dilated
so that its round corners are never cut (shapely, prepared, vectorised over the segments).

:func:`paper_circle_redundant` is the paper's own test for one circle (collinear nodes; an obtuse
angle at an end of the segment in triangle O-A_x-A_y); tests check it agrees with the rule above.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import shapely
from shapely.geometry import Polygon
from shapely.geometry.base import BaseGeometry

from companion.planning.errors import PlanningError
from companion.planning.grid import dilate
from uav_model.world import World

_FIRST_CHUNK = 32  # candidate segments tested per vectorised call; doubles while all are clear


class _Obstacles:
    """Exact discs and prepared polygons, asked "which of these segments from a are clear?"."""

    def __init__(self, obstacles: Sequence[BaseGeometry] | World, extra: Sequence[BaseGeometry], clearance_m: float):
        polygons: list[BaseGeometry] = list(extra)
        centres: list[tuple[float, float]] = []
        radii: list[float] = []
        if isinstance(obstacles, World):
            for o in obstacles.static_obstacles:
                if o.is_circle:
                    centres.append(o.center)
                    radii.append(o.inflated_radius_m)
                else:
                    polygons.append(dilate(o.footprint, o.margin_m))
        else:
            polygons.extend(obstacles)
        self.centres = np.asarray(centres, dtype=float).reshape(-1, 2)
        self.safe_radii = np.asarray(radii, dtype=float) + clearance_m
        self.clearance_m = clearance_m
        polygons = [p for p in polygons if not p.is_empty]
        self.union = shapely.union_all(polygons) if polygons else None
        if self.union is not None:
            shapely.prepare(self.union)

    def clear_from(self, a: np.ndarray, bs: np.ndarray) -> np.ndarray:
        """bool (K,): does the segment a -> bs[k] keep clear of every obstacle?"""
        ok = np.ones(len(bs), dtype=bool)
        if len(self.centres):
            d = bs - a                                        # (K, 2)
            len2 = np.einsum("kj,kj->k", d, d)[:, None]       # (K, 1)
            t = d @ (self.centres - a).T                      # (K, C)
            t = np.clip(np.divide(t, len2, out=np.zeros_like(t), where=len2 > 0), 0.0, 1.0)
            closest = a + t[:, :, None] * d[:, None, :]       # (K, C, 2)
            dist = np.linalg.norm(self.centres[None, :, :] - closest, axis=2)
            ok &= np.all(dist > self.safe_radii[None, :], axis=1)
        if self.union is not None and ok.any():
            segments = shapely.linestrings(np.stack([np.broadcast_to(a, bs.shape), bs], axis=1))
            if self.clearance_m > 0:
                ok &= ~shapely.dwithin(self.union, segments, self.clearance_m)
            else:
                ok &= ~shapely.intersects(self.union, segments)
        return ok


def sparsify(path: np.ndarray, obstacles_inflated: Sequence[Polygon] | World, *, clearance_m: float = 0.0,
             extra: Sequence[BaseGeometry] = ()) -> np.ndarray:
    """The key nodes of ``path`` (N, 2): a subsequence with the same first and last point.

    ``obstacles_inflated`` is either a World (its static obstacles, inflated; circles exact) or
    the inflated polygons themselves. ``extra`` geometries must be kept clear of too (e.g. the
    side constraint of a lower-priority vehicle). A node is only dropped for a clear shortcut, so
    the result is never longer than the input and never closer to an obstacle than its segments.
    """
    p = np.asarray(path, dtype=float)
    if p.ndim != 2 or p.shape[1] != 2 or len(p) == 0:
        raise PlanningError(f"path must be an (N, 2) array of points, got shape {p.shape}")
    if not np.isfinite(p).all():
        raise PlanningError("path contains a non-finite coordinate")
    if not (np.isfinite(clearance_m) and clearance_m >= 0):
        raise PlanningError(f"clearance_m must be a non-negative number, got {clearance_m!r}")
    n = len(p)
    if n <= 2:
        return p.copy()
    obstacles = _Obstacles(obstacles_inflated, extra, float(clearance_m))
    keep = [0]
    anchor = 0
    while anchor < n - 1:
        nxt = n - 1
        lo, chunk = anchor + 2, _FIRST_CHUNK
        while lo < n:
            hi = min(n, lo + chunk)
            ok = obstacles.clear_from(p[anchor], p[lo:hi])
            if not ok.all():
                nxt = lo + int(np.argmin(ok)) - 1  # the middle node of the first blocked triple stays
                break
            lo, chunk = hi, 2 * chunk
        keep.append(nxt)
        anchor = nxt
    return p[keep]


def paper_circle_redundant(a, mid, b, center, safe_radius: float) -> bool:
    """The paper's test: is ``mid`` redundant between path nodes ``a`` and ``b`` for circle O?

    Preconditions (those of a valid path): ``a`` and ``b`` lie outside the circle, and the path
    a -> mid -> b does not enter it. Then: collinear nodes (angle 0) -> redundant; an obtuse (or
    right) angle at a or b in triangle O-a-b -> the closest point of segment ab to O is an end,
    which is outside -> redundant; otherwise redundant iff the distance from O to line ab exceeds
    ``safe_radius``.
    """
    a, mid, b, o = (np.asarray(v, dtype=float) for v in (a, mid, b, center))
    u, v = mid - a, b - mid
    cross_uv = u[0] * v[1] - u[1] * v[0]
    if abs(cross_uv) <= 1e-12 * np.hypot(*u) * np.hypot(*v) and float(np.dot(u, v)) > 0:
        return True
    ab = b - a
    if float(np.dot(o - a, ab)) <= 0 or float(np.dot(o - b, -ab)) <= 0:
        return True
    distance = abs(ab[0] * (o - a)[1] - ab[1] * (o - a)[0]) / float(np.hypot(*ab))
    return bool(distance > safe_radius)
