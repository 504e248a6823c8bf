"""The limits a mission is held to beyond its schema's, each named in the error that enforces it.

The file and the YAML (:mod:`mission_read`): its size, nesting and number of values. The grid
(:func:`grid_shape`, shared with :mod:`companion.planning.grid`): A* keeps about 50 bytes per cell,
so a grid of :data:`MAX_GRID_CELLS` needs about 200 MB; the loader refuses a finer one up front.
"""

from __future__ import annotations

import math

MAX_FILE_BYTES = 4 * 1024 * 1024  # a mission at every schema limit, in lat/lon, is about 3 MB
MAX_DEPTH = 20  # a mission nests 6 deep (obstacles[i].motion.waypoints[j].lat_deg)
MAX_NODES = 600_000  # 200 polygons of 256 lat/lon vertices with a 100-point patrol each: ~400,000
MAX_GRID_CELLS = 4_000_000


def grid_shape(bounds: tuple[float, float, float, float], resolution_m: float) -> tuple[int, int]:
    """(nx, ny) cells of a grid of ``resolution_m`` over ``bounds`` (x0, y0, x1, y1)."""
    x0, y0, x1, y1 = bounds
    nx = max(1, math.ceil((x1 - x0) / resolution_m - 1e-9))
    ny = max(1, math.ceil((y1 - y0) / resolution_m - 1e-9))
    return nx, ny
