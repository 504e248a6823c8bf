"""The sightline critic's slope where the paper's has none: how close an open sight line is to
being blocked.

With the paper's S (depth of the obstacles crossing the sight segment) every candidate whose
sight line is open scores 0, so the critic cannot say which way the line closes. The sloped S is
the depth when blocked, as printed, and minus the sight segment's clearance to the nearest true
obstacle (capped) when it is open: a candidate that brings the line closer to an obstacle edge
scores higher, and the step to "blocked" is continuous (0 on the edge).
"""

from __future__ import annotations

import numpy as np

from companion.planning.dwa.geometry import polygon_signed_distance
from companion.planning.dwa.snapshot import ObstacleSnapshot


def points_to_segments(px: np.ndarray, py: np.ndarray, ex: np.ndarray, ey: np.ndarray,
                       q: tuple[float, float]) -> np.ndarray:
    """Distance (M, S) from M points to the S segments (ex, ey)[i] -> q."""
    dx, dy = q[0] - ex, q[1] - ey
    len2 = np.maximum(dx * dx + dy * dy, 1e-12)
    rx = px[:, None] - ex
    ry = py[:, None] - ey
    u = np.clip((rx * dx + ry * dy) / len2, 0.0, 1.0)
    return np.hypot(rx - u * dx, ry - u * dy)


def open_clearance(ex: np.ndarray, ey: np.ndarray, q: tuple[float, float], t_s: float,
                   snap: ObstacleSnapshot) -> np.ndarray:
    """The clearance (S,) of each sight segment (ex, ey)[i] -> q to the nearest TRUE obstacle
    predicted to ``t_s``; meaningful where the segment crosses none (0 or less where it does).

    Between a segment and a polygon the nearest pair has a polygon vertex or a segment end in it,
    so vertices-to-segment and ends-to-polygon cover it; a circle is its centre's distance minus R.
    """
    best = np.full(len(ex), np.inf)
    if snap.circle_ids:
        centres = snap.circle_xy_m + snap.circle_vel_m_s * t_s
        d = points_to_segments(centres[:, 0], centres[:, 1], ex, ey, q) - snap.circle_radius_m[:, None]
        best = np.minimum(best, d.min(axis=0))
    if snap.poly_ids:
        verts = (snap.poly_a_m + (snap.poly_vel_m_s * t_s)[:, None, :]).reshape(-1, 2)
        best = np.minimum(best, points_to_segments(verts[:, 0], verts[:, 1], ex, ey, q).min(axis=0))
        n_s = len(ex)
        ends = polygon_signed_distance(np.append(ex, q[0]), np.append(ey, q[1]), np.full(n_s + 1, t_s), snap)
        best = np.minimum(best, np.minimum(ends[:, :n_s].min(axis=0), float(ends[:, n_s].min())))
    return best
