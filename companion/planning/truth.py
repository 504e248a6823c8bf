"""The world's TRUE obstacle footprints as vectorised path queries (the clearance of moving
segments, sight-line blocking), and the segment distances the success criteria use: the
geometry behind :mod:`companion.planning.metrics` (which re-exports it) and the headless
runner's safety batches."""

from __future__ import annotations

import math

import numpy as np
import shapely

from uav_model.world import World


class TruthGeometry:
    """The world's TRUE obstacle footprints, prepared once, with vectorised path queries."""

    def __init__(self, world: World):
        self.world = world
        self.circles = [o for o in world.obstacles if o.is_circle]
        self.polygons = [o for o in world.obstacles if not o.is_circle]
        fixed = [o for o in self.circles if not o.is_moving]
        self._moving_circles = [o for o in self.circles if o.is_moving]
        self._c_xy = np.array([o.center for o in fixed], dtype=float).reshape(-1, 2)
        self._c_r = np.array([o.size_m for o in fixed], dtype=float)
        for o in self.polygons:
            shapely.prepare(o.footprint)
        # Each polygon's bounding disc (about its reference centre), for skipping the exact
        # distance where the disc alone shows the polygon is not the nearest footprint.
        self._p_bound = [(o.center, float(np.hypot(*(o.vertices() - o.center).T).max())) for o in self.polygons]
        # A disc holding each footprint wherever its motion takes it (fixed circles, moving
        # circles, polygons): a contact check skips the obstacles no segment comes near.
        sweep = [(o.center, o.size_m, o.motion.offset_disc) for o in fixed + self._moving_circles]
        sweep += [(c, bound, o.motion.offset_disc) for o, (c, bound) in zip(self.polygons, self._p_bound)]
        self._sweep_xy = np.array([(c[0] + d[0], c[1] + d[1]) for c, _, (d, _) in sweep], dtype=float).reshape(-1, 2)
        self._sweep_r = np.array([r + dr for _, r, (_, dr) in sweep], dtype=float)

    def segment_clearance_m(self, x0: np.ndarray, y0: np.ndarray, x1: np.ndarray, y1: np.ndarray,
                            t0: np.ndarray, t1: np.ndarray, upto_m: float = math.inf) -> np.ndarray:
        """Smallest distance (N,) from each moving segment to any true footprint; 0 = contact.

        ``upto_m``: clearances beyond it come back as ``upto_m`` (for a contact check: obstacles
        that far from every segment need no exact distance). Exact below it.
        """
        x0, y0, x1, y1 = (np.atleast_1d(np.asarray(a, dtype=float)) for a in (x0, y0, x1, y1))
        best = np.full(x0.shape, float(upto_m))
        near = self._near_sweeps(x0, y0, x1, y1, upto_m)  # per obstacle: may come within upto_m
        n_c, n_m = len(self._c_r), len(self._moving_circles)
        if n_c and near[:n_c].any():  # static discs, all at once: (N, C)
            cx, cy = self._c_xy[:, 0], self._c_xy[:, 1]
            d = _origin_to_segment(x0[:, None] - cx, y0[:, None] - cy, x1[:, None] - cx, y1[:, None] - cy)
            best = np.minimum(best, (d - self._c_r).min(axis=1))
        if not (self._moving_circles or self.polygons):
            return np.maximum(best, 0.0)
        t0, t1 = (np.atleast_1d(np.asarray(a, dtype=float)) for a in (t0, t1))
        for o, needed in zip(self._moving_circles, near[n_c:n_c + n_m]):
            if not needed:
                continue
            o0, o1 = o.offset_at(t0), o.offset_at(t1)
            cx, cy = o.center
            best = np.minimum(best, _origin_to_segment(x0 - o0[..., 0] - cx, y0 - o0[..., 1] - cy,
                                                       x1 - o1[..., 0] - cx, y1 - o1[..., 1] - cy) - o.size_m)
        for o, ((cx, cy), bound), needed in zip(self.polygons, self._p_bound, near[n_c + n_m:]):
            if not needed:
                continue
            if o.is_moving:  # in the obstacle's frame
                o0, o1 = o.offset_at(t0), o.offset_at(t1)
                ax, ay, bx, by = x0 - o0[..., 0], y0 - o0[..., 1], x1 - o1[..., 0], y1 - o1[..., 1]
            else:
                ax, ay, bx, by = x0, y0, x1, y1
            # The distance to the bounding disc is a lower bound of the distance to the polygon:
            # where it is no smaller than the best so far, the polygon cannot change the result.
            near = _origin_to_segment(ax - cx, ay - cy, bx - cx, by - cy) - bound < best
            if not near.any():
                continue
            a = np.stack([ax[near], ay[near]], axis=-1)
            b = np.stack([bx[near], by[near]], axis=-1)
            best[near] = np.minimum(best[near], shapely.distance(shapely.linestrings(np.stack([a, b], axis=-2)),
                                                                 o.footprint))
        return np.maximum(best, 0.0)

    def _near_sweeps(self, x0: np.ndarray, y0: np.ndarray, x1: np.ndarray, y1: np.ndarray,
                     upto_m: float) -> np.ndarray:
        """Per obstacle (fixed circles, moving circles, polygons): whether any segment comes
        within ``upto_m`` (+ 1 mm for rounding) of the disc its footprint sweeps; all True when
        ``upto_m`` is infinite. An obstacle outside it is farther than ``upto_m`` from every
        segment (in its own frame too: the offsets between two times stay in the disc), so it
        cannot change a clearance capped at ``upto_m``."""
        if not math.isfinite(upto_m) or not len(self._sweep_r) or not x0.size:
            return np.ones(len(self._sweep_r), dtype=bool)
        cx, cy = self._sweep_xy[:, 0], self._sweep_xy[:, 1]
        d = _origin_to_segment(x0[:, None] - cx, y0[:, None] - cy, x1[:, None] - cx, y1[:, None] - cy)
        return (d.min(axis=0) - self._sweep_r <= upto_m + 1e-3)

    def sight_blocked(self, ax: np.ndarray, ay: np.ndarray, bx: np.ndarray, by: np.ndarray,
                      t_s: np.ndarray) -> np.ndarray:
        """Whether the segment a-b at time t crosses any true footprint (N,) bool."""
        ax, ay, bx, by, t_s = (np.atleast_1d(np.asarray(a, dtype=float)) for a in (ax, ay, bx, by, t_s))
        blocked = np.zeros(ax.shape, dtype=bool)
        for o in self.circles:
            off = o.offset_at(t_s)
            cx, cy = o.center[0] + off[..., 0], o.center[1] + off[..., 1]
            blocked |= _origin_to_segment(ax - cx, ay - cy, bx - cx, by - cy) < o.size_m
        for o, ((cx, cy), bound) in zip(self.polygons, self._p_bound):
            off = o.offset_at(t_s)
            sx, sy, ex, ey = ax - off[..., 0], ay - off[..., 1], bx - off[..., 0], by - off[..., 1]
            # Only a segment that reaches the polygon's bounding disc (1 mm of slack for rounding)
            # can cross it, and one already blocked stays so: shapely sees the others only.
            test = ~blocked & (_origin_to_segment(sx - cx, sy - cy, ex - cx, ey - cy) <= bound + 1e-3)
            if not test.any():
                continue
            coords = np.stack([np.stack([sx[test], sy[test]], axis=-1), np.stack([ex[test], ey[test]], axis=-1)],
                              axis=-2)
            blocked[test] = shapely.intersects(shapely.linestrings(coords), o.footprint)
        return blocked


def _origin_to_segment(ax, ay, bx, by):
    """Distance from the origin to segments a-b (arrays)."""
    dx, dy = bx - ax, by - ay
    len2 = dx * dx + dy * dy
    # np.clip's result, at a third of its cost per call (it runs per obstacle per safety batch);
    # only the sign of a zero u can differ, which np.hypot does not see.
    u = np.minimum(np.maximum(-(ax * dx + ay * dy) / np.where(len2 > 0, len2, 1.0), 0.0), 1.0)
    return np.hypot(ax + u * dx, ay + u * dy)


def pair_min_distance(a0x, a0y, a1x, a1y, b0x, b0y, b1x, b1y) -> np.ndarray:
    """Closest approach of two vehicles each moving linearly over the same interval."""
    return _origin_to_segment(np.asarray(a0x) - b0x, np.asarray(a0y) - b0y,
                              np.asarray(a1x) - b1x, np.asarray(a1y) - b1y)


def inside_fence(world: World, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    m = world.geofence_margin_m
    return ((world.x_min_m - m <= x) & (x <= world.x_max_m + m)
            & (world.y_min_m - m <= y) & (y <= world.y_max_m + m))
