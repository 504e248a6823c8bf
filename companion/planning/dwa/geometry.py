"""Geometry kernels on snapshot arrays: signed clearance of many points at many times to every
inflated obstacle, and point-to-segment distance."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from companion.planning.dwa.snapshot import ObstacleSnapshot


def to_segment(px: np.ndarray, py: np.ndarray, x_m: float, y_m: float, to_xy: tuple[float, float]) -> np.ndarray:
    """Distance from points (px, py) to the segment (x, y) -> to_xy."""
    dx, dy = to_xy[0] - x_m, to_xy[1] - y_m
    rx, ry = px - x_m, py - y_m
    len2 = dx * dx + dy * dy
    if len2 == 0.0:
        return np.hypot(rx, ry)
    u = np.minimum(np.maximum((rx * dx + ry * dy) / len2, 0.0), 1.0)
    return np.hypot(rx - u * dx, ry - u * dy)



def inflated_clearance(px: np.ndarray, py: np.ndarray, t_s: np.ndarray, snap: ObstacleSnapshot) -> np.ndarray:
    """Signed clearance (O, N) of N points (px, py) at times t_s (all (N,)) to each inflated
    obstacle predicted at constant velocity; negative inside. Rows: circles, then polygons.

    Obstacles run along the first axis and points along the second, so that every elementwise
    operation streams over the points and every reduction over obstacles or edges is a
    row-wise one: numpy is several times slower reducing a short last axis. The compiled twin
    is :func:`.geometry_jit.inflated_clearance`.
    """
    parts = []
    if snap.circle_ids:
        parts.append(_circle_distance(px, py, t_s, snap) - snap.circle_margin_m[:, None])
    if snap.poly_ids:
        parts.append(polygon_signed_distance(px, py, t_s, snap) - snap.poly_margin_m[:, None])
    if not parts:
        return np.zeros((0, len(px)))
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


# The polygon kernel works on (P, E, N) temporaries. Above glibc's mmap threshold (128 KiB) each
# one is mapped and unmapped afresh, several times slower per element (a 31 x 23 window stays
# below it; a speed window would not): points go through in chunks that stay below.
_CHUNK_BYTES = 120 * 1024


def polygon_signed_distance(px: np.ndarray, py: np.ndarray, t_s: np.ndarray, snap: ObstacleSnapshot) -> np.ndarray:
    """Distance (P, N) from points at times t_s to each TRUE polygon, negative inside."""
    chunk = max(64, _CHUNK_BYTES // (8 * snap.poly_a_m.shape[0] * max(1, snap.poly_a_m.shape[1])))
    if len(px) <= chunk:
        return _polygon_signed_distance(px, py, t_s, snap)
    return np.concatenate([_polygon_signed_distance(px[i:i + chunk], py[i:i + chunk], t_s[i:i + chunk], snap)
                           for i in range(0, len(px), chunk)], axis=1)


def one_layout(a: np.ndarray) -> np.ndarray:
    """``a`` as a writable C-contiguous array (a copy only when it is not one): numba compiles,
    or loads from its cache, one signature per layout and read-only flag, at the first call with
    it. One layout keeps that to the first tick (companion.app.warmup pays it before the flight)."""
    return a if a.flags.carray else np.array(a, order="C")  # carray: C-contiguous, aligned and writable


def _circle_distance(px: np.ndarray, py: np.ndarray, t_s: np.ndarray, snap: ObstacleSnapshot) -> np.ndarray:
    """Signed distance (C, N) from points at times t_s to each true circle, predicted."""
    c, v = snap.circle_xy_m, snap.circle_vel_m_s
    dx = px - c[:, 0:1]
    dy = py - c[:, 1:2]
    if np.any(v):
        dx -= v[:, 0:1] * t_s
        dy -= v[:, 1:2] * t_s
    return np.hypot(dx, dy) - snap.circle_radius_m[:, None]


def _polygon_signed_distance(px: np.ndarray, py: np.ndarray, t_s: np.ndarray,
                             snap: ObstacleSnapshot) -> np.ndarray:
    """Distance (P, N) from points at times t_s to each true polygon, negative inside
    (crossing number). A moving polygon is handled in its own frame: the points move by -v t.
    All work is on (P, E, N) arrays, in place where possible: this is the hot loop.
    """
    a, d = snap.poly_a_m, snap.poly_d_m
    abx, aby = d[..., 0:1], d[..., 1:2]  # (P, E, 1)
    qx, qy = px, py
    if snap.polygons_move:
        qx = px - (snap.poly_vel_m_s[:, 0:1] * t_s)[:, None, :]  # (P, 1, N)
        qy = py - (snap.poly_vel_m_s[:, 1:2] * t_s)[:, None, :]
    apx = qx - a[..., 0:1]  # (P, E, N)
    apy = qy - a[..., 1:2]
    # Crossing number (before apx/apy are reused): edges straddling the point's row whose
    # crossing lies right of the point. Compared on the raw coordinates, as the textbook test
    # does, so a point level with a vertex is counted consistently.
    straddle = (a[..., 1:2] > qy) != (snap.poly_b_m[..., 1:2] > qy)
    straddle &= apx < apy * snap.poly_dx_per_dy[..., None]
    inside = np.logical_xor.reduce(straddle, axis=1)
    # Distance to each edge segment, then the nearest edge of each polygon.
    u = apx * abx
    u += apy * aby
    u *= snap.poly_inv_len2[..., None]
    np.maximum(u, 0.0, out=u)  # clip to [0, 1]; np.clip costs more per call
    np.minimum(u, 1.0, out=u)
    apx -= u * abx
    apy -= u * aby
    apx *= apx
    apy *= apy
    apx += apy
    dist = np.sqrt(apx.min(axis=1))
    dist[inside] *= -1.0
    return dist
