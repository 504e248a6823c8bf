"""The compiled twin (numba) of :mod:`.heading`'s critic: the same numbers bit for bit (see
:mod:`.jit`)."""

from __future__ import annotations

import numpy as np

from companion.planning.dwa.geometry import one_layout
from companion.planning.dwa.heading import resolve_single
from companion.planning.dwa.jit import inline, jit
from companion.planning.dwa.types import LocalGoals


def heading_from_ends(ex: np.ndarray, ey: np.ndarray, final_heading: np.ndarray, goals: LocalGoals,
                      origin: tuple[float, float], px: np.ndarray | None, py: np.ndarray | None,
                      single: bool | None = None, soonest_deg: float = 0.0) -> np.ndarray:
    """:func:`.heading.heading_from_ends`, compiled: one pass toward one target, or over the
    goal window (one layout per argument, see :func:`.geometry.one_layout`)."""
    if resolve_single(ex, ey, goals, origin, single):
        tx, ty = goals.first_xy
        # Contiguous copies (S floats): the ends arrive as views or as arrays by the path taken, and
        # each layout is a compiled signature of its own (loaded, or compiled, at its first call).
        return _heading_toward(np.ascontiguousarray(ex), np.ascontiguousarray(ey), final_heading, tx, ty)
    window = (one_layout(goals.nodes_xy), one_layout(goals.prev_nodes_xy), one_layout(goals.radius2_m2),
              bool(goals.ends_at_station), float(soonest_deg))
    return _heading_goals(one_layout(ex), one_layout(ey), one_layout(final_heading), one_layout(px), one_layout(py),
                          window)


@jit
def _heading_toward(ex, ey, final_heading, tx, ty):
    """The heading critic (S,) toward one target (tx, ty): 180 - |heading - bearing| in deg.
    A rollout whose prediction point is the one before's (a speed window's hovers share theirs)
    reuses its bearing: the same nonzero differences give arctan2 the same arguments (a zero
    is worked out again, as its sign counts)."""
    out = np.empty(len(ex))
    bearing = dx0 = dy0 = 0.0
    for i in range(len(ex)):
        dy = ty - ey[i]
        dx = tx - ex[i]
        if i == 0 or dx != dx0 or dy != dy0 or dx == 0.0 or dy == 0.0:
            bearing = np.arctan2(dy, dx)
            dx0, dy0 = dx, dy
        deviation = abs((final_heading[i] - bearing + np.pi) % (2.0 * np.pi) - np.pi)
        out[i] = 180.0 - np.degrees(deviation)
    return out


@jit
def _heading_goals(ex, ey, final_heading, px, py, goals):
    """heading_from_ends' window path: each rollout (S, K + 1) scored toward the first goal of
    ``nodes`` (G, 2) it does not reach (a point within radius2 of it, or its prediction point
    past it, from ``prev``); an arriving rollout (``ends_at_station``) scores 180 less
    soonest_deg times the fraction of the horizon it takes to get inside the station's radius."""
    return heading_goals_rows(ex, ey, final_heading, px, py, np.arange(len(ex)), goals)


@inline
def heading_goals_rows(ex, ey, final_heading, px, py, rows, goals):
    """:func:`_heading_goals` with rollout i's points in row ``rows[i]`` of (px, py) (the
    distinct rollouts of a speed window: its hovers share one), (ex[i], ey[i]) that row's last
    point: the goal reached, the bearing to the next and the arrival are worked out once per
    row, and a goal counts as reached at its first point within the radius."""
    nodes, prev, radius2, ends_at_station, soonest_deg = goals
    n_s, n_k = len(ex), px.shape[1]
    count = len(nodes)
    done = np.zeros(px.shape[0], dtype=np.bool_)
    arrives = np.zeros(px.shape[0], dtype=np.bool_)
    value = np.empty(px.shape[0])  # per row: the arrival score, or the bearing to the goal held
    out = np.empty(n_s)
    for i in range(n_s):
        r = rows[i]
        if not done[r]:
            done[r] = True
            n = count
            for j in range(count):
                gx, gy = nodes[j, 0], nodes[j, 1]
                reached = False
                if not (ends_at_station and j == count - 1):  # passed: the points need not be read
                    reached = (ex[i] - gx) * (gx - prev[j, 0]) + (ey[i] - gy) * (gy - prev[j, 1]) > 0.0
                if not reached:
                    for k in range(n_k):
                        dx = px[r, k] - gx
                        dy = py[r, k] - gy
                        if dx * dx + dy * dy <= radius2[j]:
                            reached = True
                            break
                if not reached:
                    n = j
                    break
            if ends_at_station and n == count:
                arrive = 180.0
                if soonest_deg > 0.0:
                    sx, sy = nodes[count - 1, 0], nodes[count - 1, 1]
                    first = 0
                    for k in range(n_k):
                        dx = px[r, k] - sx
                        dy = py[r, k] - sy
                        if dx * dx + dy * dy <= radius2[count - 1]:
                            first = k
                            break
                    arrive -= soonest_deg * first / (n_k - 1)
                arrives[r] = True
                value[r] = arrive
            else:
                t = min(n, count - 1)
                value[r] = np.arctan2(nodes[t, 1] - ey[i], nodes[t, 0] - ex[i])
        if arrives[r]:
            out[i] = value[r]
            continue
        deviation = abs((final_heading[i] - value[r] + np.pi) % (2.0 * np.pi) - np.pi)
        out[i] = 180.0 - np.degrees(deviation)
    return out
