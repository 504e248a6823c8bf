"""The sightline critic S (BDWA's own term, paper eq. 9): how deep the obstacles that cross the
UAV-UAV sight segment are."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from companion.planning.dwa.snapshot import ObstacleSnapshot
from companion.planning.dwa.types import OtherUav, Pose

if TYPE_CHECKING:
    from companion.planning.dwa.config import DwaConfig


def sightline_scores(ends: np.ndarray, other_xy: tuple[float, float], t_s: float,
                     snap: ObstacleSnapshot) -> np.ndarray:
    """The sightline distance (S,) for sight segments ends[i] -> other_xy, uncapped.

    For each TRUE obstacle (predicted to ``t_s``) that the segment crosses, d_O is the smaller
    of the obstacle's extents left and right of the segment's line; the result is the largest
    d_O, or 0 when nothing crosses.
    """
    return sightline_depths(ends[:, 0], ends[:, 1], other_xy, t_s, snap)


def sightline_depths(ex: np.ndarray, ey: np.ndarray, other_xy: tuple[float, float], t_s: float,
                     snap: ObstacleSnapshot, keep: np.ndarray | None = None) -> np.ndarray:
    """sightline_scores for ends (ex, ey), each (S,), over the obstacles where ``keep`` (a mask,
    circles then polygons; all when None).

    Every sight segment ends at q = other_xy, so everything is measured from q: for a point
    w (relative to q), w . n_i is its signed distance from sight line i (n_i its unit left
    normal) and w . d_i its position along it (d_i = q - end_i). One (rows, 2) @ (2, 2S)
    product gives both for every circle centre, polygon vertex and edge vector at once; the
    rest is a handful of elementwise operations on the (rows, S) blocks.
    """
    qx, qy = other_xy
    dx = qx - ex
    dy = qy - ey
    n_s = len(ex)
    len2 = np.maximum(dx * dx + dy * dy, 1e-12)
    inv_len = 1.0 / np.sqrt(len2)
    basis = np.empty((2, 2 * n_s))  # [n | d]
    basis[0, :n_s] = -dy * inv_len
    basis[1, :n_s] = dx * inv_len
    basis[0, n_s:] = dx
    basis[1, n_s:] = dy
    c_xy, c_vel, c_r, p_a, p_d, p_vel = _kept(snap, keep)
    n_c, n_p = len(c_r), len(p_a)
    parts = []
    if n_c:
        parts.append(c_xy + (c_vel * t_s - (qx, qy)))
    if n_p:
        n_e = p_a.shape[1]
        shift = p_vel * t_s - (qx, qy)
        parts.append((p_a + shift[:, None, :]).reshape(-1, 2))  # vertices, from q
        parts.append(p_d.reshape(-1, 2))  # edge vectors
    m = (parts[0] if len(parts) == 1 else np.concatenate(parts)) @ basis
    best = np.zeros(n_s)
    if n_c:
        side, along = m[:n_c, :n_s], m[:n_c, n_s:]  # centre: from the line; along it, from q
        # The closest point of segment i to the centre: its position u in [0, 1] from the end.
        u = along / len2 + 1.0
        over = u - np.minimum(np.maximum(u, 0.0), 1.0)
        r = c_r[:, None]
        crosses = side * side + over * over * len2 < r * r
        best = np.where(crosses, r - np.abs(side), 0.0).max(axis=0)
    if n_p:
        k0, k1 = n_c + n_p * n_e, n_c + 2 * n_p * n_e
        sa, pa = m[n_c:k0, :n_s], m[n_c:k0, n_s:]  # each edge's start (a vertex)
        sd, pd = m[k0:k1, :n_s], m[k0:k1, n_s:]  # each edge's vector
        # An edge crosses the segment if it straddles the line at a point between the ends:
        # at k = sa / -sd along the edge, whose position along the line from q is pa + k pd,
        # in [-|d|^2, 0].
        straddle = (sa > 0.0) != (sa + sd > 0.0)
        w = pa + sa / np.where(straddle, -sd, 1.0) * pd
        straddle &= (w >= -len2) & (w <= 0.0)
        crossed = straddle.reshape(n_p, n_e, n_s).any(axis=1)  # (P, S)
        sa = sa.reshape(n_p, n_e, n_s)
        d_o = np.where(crossed, np.minimum(sa.max(axis=1), -sa.min(axis=1)), 0.0)
        best = np.maximum(best, d_o.max(axis=0))
    return best


def _kept(snap: ObstacleSnapshot, keep: np.ndarray | None) -> tuple[np.ndarray, ...]:
    """The snapshot's circles (xy, velocity, radius) and polygons (vertices, edge vectors,
    velocity), only those ``keep`` marks (circles first, then polygons) when given."""
    c_xy, c_vel, c_r = snap.circle_xy_m, snap.circle_vel_m_s, snap.circle_radius_m
    p_a, p_d, p_vel = snap.poly_a_m, snap.poly_d_m, snap.poly_vel_m_s
    if keep is None:
        return c_xy, c_vel, c_r, p_a, p_d, p_vel
    kc, kp = keep[:len(c_r)], keep[len(c_r):]
    return c_xy[kc], c_vel[kc], c_r[kc], p_a[kp], p_d[kp], p_vel[kp]


def sightline_term(pose: Pose, other: OtherUav | None, snapshot: ObstacleSnapshot, config: DwaConfig,
               ex: np.ndarray, ey: np.ndarray) -> np.ndarray | None:
    """S (capped; sloped when the config says so, see :mod:`.sightline_slope`) for prediction
    points (ex, ey), or None when the term is off: no other UAV,
    w_s = 0, or the other UAV has arrived (a parked UAV is no one to hide from, and a term that
    is non-zero for few candidates would outbid the heading critic under sum normalisation)."""
    if other is None or other.arrived or config.w_s <= 0 or not snapshot.count:
        return None
    t_p = config.horizon_s
    q = (other.x_m + other.vx_m_s * t_p, other.y_m + other.vy_m_s * t_p)
    # Sight lines run from somewhere within reach of the pose to q: skip obstacles far from both
    # (the slope reads obstacles up to the cap beyond: nearer than that, an open line is scored).
    slope = config.sightline_slope
    reach = config.reach_m + (config.sightline_cap_m if slope else 0.0)
    backend = config.backend
    culled = backend.cull(snapshot, pose.x_m, pose.y_m, reach, t_p, to_xy=q)
    if not culled.count:
        return None
    keep = None if culled.count == len(culled.keep) else culled.keep
    depth = np.minimum(config.sightline_cap_m, backend.sightline_depths(ex, ey, q, t_p, snapshot, keep))
    if not slope:
        return depth
    gap = np.minimum(backend.open_clearance(ex, ey, q, t_p, culled.subset()), config.sightline_cap_m)
    return np.where(depth > 0.0, depth, -np.maximum(gap, 0.0))
