"""Hypothesis strategies for random planning worlds (shared by the planning-core unit tests).

A square area with a few static circles, rectangles and triangles, inflated by the paper's 20 %,
in the shape of SPEC §3's random scenarios but small enough for fast grids.
"""

from __future__ import annotations

from hypothesis import strategies as st

from uav_model.world import Obstacle, World, make_obstacle

SIDE_M = 1000.0
MARGIN_M = 50.0


@st.composite
def obstacles(draw, index: int) -> Obstacle:
    kind = draw(st.sampled_from(["circle", "rectangle", "triangle"]))
    center = (draw(st.floats(150.0, SIDE_M - 150.0)), draw(st.floats(150.0, SIDE_M - 150.0)))
    size = draw(st.floats(30.0, 180.0))
    rotation = draw(st.floats(0.0, 180.0))
    if kind == "circle":
        return make_obstacle(f"o{index}", "circle", center=center, radius_m=size)
    if kind == "rectangle":
        aspect = draw(st.floats(0.3, 1.0))
        return make_obstacle(f"o{index}", "rectangle", center=center, width_m=1.5 * size,
                             height_m=1.5 * size * aspect, rotation_deg=rotation)
    return make_obstacle(f"o{index}", "triangle", center=center, circumradius_m=size, rotation_deg=rotation)


@st.composite
def worlds(draw, min_obstacles: int = 1, max_obstacles: int = 5) -> World:
    n = draw(st.integers(min_obstacles, max_obstacles))
    obs = tuple(draw(obstacles(i)) for i in range(n))
    return World(0.0, 0.0, SIDE_M, SIDE_M, MARGIN_M, obs)


def points() -> st.SearchStrategy[tuple[float, float]]:
    """A point anywhere in the area (callers reject the ones inside obstacles)."""
    return st.tuples(st.floats(0.0, SIDE_M), st.floats(0.0, SIDE_M))
