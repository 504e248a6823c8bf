"""Occupancy grid for A*: the inflated static obstacles rasterised over the geofence box, with
everything outside the declared area (the keep-in, :func:`uav_model.fence_margin.keep_in_box`) occupied.

Cell (ix, iy) covers ``[x0 + ix*res, x0 + (ix+1)*res) x [y0 + iy*res, y0 + (iy+1)*res)``; the
array is indexed ``occupied[iy, ix]`` (rows are y, north). A cell is occupied when its centre
lies within ``h = res*sqrt(2)/2`` of an inflated obstacle. Every point of a move between two
8-neighbour cell centres is within h of one of its ends, so a straight or diagonal move between
free centres never touches an inflated obstacle: the grid is conservative by construction.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

from companion.planning.errors import PlanningError
from uav_model.fence_margin import keep_in_box
from uav_model.mission_limits import MAX_GRID_CELLS as MAX_CELLS, grid_shape
from uav_model.world import World

# Dilating a polygon with a buffer puts the arc vertices ON the true offset curve, so the chords
# cut inside it. Scaling the distance by 1/cos(pi/(4*q)) makes the arcs circumscribe the curve:
# the dilation is then never smaller than the exact one, and at most 0.12 % larger (q = 16).
_DILATE_QUAD_SEGS = 16
_CIRCUMSCRIBE = 1.0 / math.cos(math.pi / (4 * _DILATE_QUAD_SEGS))


@dataclass(frozen=True, eq=False)
class OccupancyGrid:
    """A read-only boolean grid in ENU metres; ``occupied`` has shape (ny, nx)."""

    origin_m: tuple[float, float]  # (x0, y0): the outer corner of cell (0, 0)
    resolution_m: float
    occupied: np.ndarray

    def __post_init__(self) -> None:
        if not (math.isfinite(self.resolution_m) and self.resolution_m > 0):
            raise PlanningError(f"grid resolution must be a positive number of metres, got {self.resolution_m!r}")
        occ = np.array(self.occupied, dtype=bool, copy=True)
        if occ.ndim != 2 or occ.size == 0:
            raise PlanningError(f"occupancy must be a non-empty 2-D array, got shape {occ.shape}")
        occ.setflags(write=False)
        object.__setattr__(self, "occupied", occ)
        object.__setattr__(self, "origin_m", (float(self.origin_m[0]), float(self.origin_m[1])))

    @property
    def shape(self) -> tuple[int, int]:
        """(ny, nx), as numpy."""
        return self.occupied.shape  # type: ignore[return-value]

    @property
    def extent_m(self) -> tuple[float, float, float, float]:
        """(x_min, y_min, x_max, y_max) of the whole grid."""
        ny, nx = self.shape
        x0, y0 = self.origin_m
        return x0, y0, x0 + nx * self.resolution_m, y0 + ny * self.resolution_m

    def world_to_cell(self, x_m: float, y_m: float) -> tuple[int, int]:
        """The cell (ix, iy) containing the point; may lie outside the grid (see ``in_bounds``)."""
        return (math.floor((x_m - self.origin_m[0]) / self.resolution_m),
                math.floor((y_m - self.origin_m[1]) / self.resolution_m))

    def cell_to_world(self, ix: int, iy: int) -> tuple[float, float]:
        """The centre of cell (ix, iy)."""
        return (self.origin_m[0] + (ix + 0.5) * self.resolution_m,
                self.origin_m[1] + (iy + 0.5) * self.resolution_m)

    def in_bounds(self, ix: int, iy: int) -> bool:
        ny, nx = self.shape
        return 0 <= ix < nx and 0 <= iy < ny

    def is_free(self, ix: int, iy: int) -> bool:
        return self.in_bounds(ix, iy) and not bool(self.occupied[iy, ix])

    def cell_centres(self) -> tuple[np.ndarray, np.ndarray]:
        """1-D arrays of the centre x (length nx) and centre y (length ny) of every column / row."""
        ny, nx = self.shape
        return _centres(self.origin_m, self.resolution_m, nx, ny)

    def with_blocked(self, extra_mask: np.ndarray) -> OccupancyGrid:
        """A new grid with the cells of ``extra_mask`` (same shape) also occupied."""
        mask = np.asarray(extra_mask, dtype=bool)
        if mask.shape != self.shape:
            raise PlanningError(f"extra mask has shape {mask.shape}, the grid has {self.shape}")
        return OccupancyGrid(self.origin_m, self.resolution_m, self.occupied | mask)

    def with_geometry_blocked(self, geometries: Sequence[BaseGeometry]) -> OccupancyGrid:
        """A new grid with the cells within h of any of ``geometries`` also occupied."""
        mask = np.zeros(self.shape, dtype=bool)
        xs, ys = self.cell_centres()
        for geom in geometries:
            _fill_within(mask, xs, ys, geom, _half_diagonal(self.resolution_m))
        return self.with_blocked(mask)


def rasterise(world: World, resolution_m: float, *, t_s: float = 0.0,
              extra: Sequence[BaseGeometry] = (), keep_in_with: Sequence[tuple[float, float]] = ()) -> OccupancyGrid:
    """Rasterise the inflated STATIC obstacles (and ``extra`` geometries) over the geofence box.

    Moving obstacles are left to the local planner. ``t_s`` places the static obstacles (their
    offset is zero; it is here so the call reads the same as the time-aware queries). Cells whose
    centre lies outside the declared area by more than half a cell are occupied too: a route stays
    in the area (within half a cell of it, where a station sits on its edge) and keeps the
    geofence margin, which is the autopilot's, clear. ``keep_in_with``: points the keep-in grows to
    take in (a vehicle planned from where it is, outside the area but inside the geofence).
    """
    if not (isinstance(resolution_m, (int, float)) and math.isfinite(resolution_m) and resolution_m > 0):
        raise PlanningError(f"grid resolution must be a positive number of metres, got {resolution_m!r}")
    fx0, fy0, fx1, fy1 = world.geofence.bounds
    nx, ny = grid_shape((fx0, fy0, fx1, fy1), resolution_m)
    if nx * ny > MAX_CELLS:
        raise PlanningError(f"a {resolution_m:g} m grid over {fx1 - fx0:g} x {fy1 - fy0:g} m is {nx} x {ny} "
                            f"cells (limit {MAX_CELLS}); use a coarser grid_resolution_m")
    xs, ys = _centres((fx0, fy0), resolution_m, nx, ny)
    h = _half_diagonal(resolution_m)
    occ = np.zeros((ny, nx), dtype=bool)
    kx0, ky0, kx1, ky1 = keep_in_box(world)
    for px, py in keep_in_with:
        kx0, ky0, kx1, ky1 = min(kx0, px), min(ky0, py), max(kx1, px), max(ky1, py)
    tol = resolution_m / 2.0 + 1e-9
    occ[:, (xs < kx0 - tol) | (xs > kx1 + tol) | (xs > fx1)] = True
    occ[(ys < ky0 - tol) | (ys > ky1 + tol) | (ys > fy1), :] = True
    for o in world.static_obstacles:
        if o.is_circle:
            _fill_disk(occ, xs, ys, o.center_at(t_s), o.inflated_radius_m + h)
        else:
            _fill_within(occ, xs, ys, o.footprint_at(t_s), o.margin_m + h)
    for geom in extra:
        _fill_within(occ, xs, ys, geom, h)
    return OccupancyGrid((fx0, fy0), float(resolution_m), occ)


def _centres(origin_m: tuple[float, float], resolution_m: float, nx: int, ny: int) -> tuple[np.ndarray, np.ndarray]:
    return (origin_m[0] + (np.arange(nx) + 0.5) * resolution_m,
            origin_m[1] + (np.arange(ny) + 0.5) * resolution_m)


def _half_diagonal(resolution_m: float) -> float:
    """h: every point of a move between 8-neighbour centres is within h of one of its ends."""
    return resolution_m * math.sqrt(2.0) / 2.0


def _index_range(centres: np.ndarray, lo: float, hi: float) -> slice:
    """Indices of the sorted cell centres within [lo, hi]."""
    return slice(int(np.searchsorted(centres, lo, side="left")), int(np.searchsorted(centres, hi, side="right")))


def _fill_disk(occ: np.ndarray, xs: np.ndarray, ys: np.ndarray, centre: tuple[float, float], radius_m: float) -> None:
    cx, cy = centre
    sx = _index_range(xs, cx - radius_m, cx + radius_m)
    sy = _index_range(ys, cy - radius_m, cy + radius_m)
    dx = xs[sx] - cx
    dy = ys[sy] - cy
    occ[sy, sx] |= dy[:, None] ** 2 + dx[None, :] ** 2 <= radius_m * radius_m


def dilate(geom: BaseGeometry, distance_m: float) -> BaseGeometry:
    """The points within ``distance_m`` of ``geom``, as a polygon that never falls short of it."""
    if distance_m <= 0:
        return geom
    return shapely.buffer(geom, distance_m * _CIRCUMSCRIBE, quad_segs=_DILATE_QUAD_SEGS)


def _fill_within(occ: np.ndarray, xs: np.ndarray, ys: np.ndarray, geom: BaseGeometry, distance_m: float) -> None:
    """Mark the cells whose centre is within ``distance_m`` of ``geom`` (never fewer)."""
    if geom.is_empty:
        return
    dilated = dilate(geom, distance_m)
    x_lo, y_lo, x_hi, y_hi = dilated.bounds
    sx = _index_range(xs, x_lo, x_hi)
    sy = _index_range(ys, y_lo, y_hi)
    if sx.start >= sx.stop or sy.start >= sy.stop:
        return
    shapely.prepare(dilated)
    gx, gy = np.meshgrid(xs[sx], ys[sy])
    occ[sy, sx] |= shapely.intersects_xy(dilated, gx, gy)
