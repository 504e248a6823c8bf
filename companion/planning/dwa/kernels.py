"""The DWA's compiled kernels in one place: those of :mod:`.kernels_point` (per point: clearances,
sightline critics, culling, the single-target heading critic and the choice), :mod:`.kernels_tick`
(heading toward a window of goals, the obstacle rule with the distance critic, the sight lines'
frame) and :mod:`.kernels_fused` (several of those in one compiled pass), each None without
numba (the ``fast`` extra), and the numpy code runs instead. Callers read them here, as
``kernels.NAME`` at call time, so that :func:`numpy_only` can switch them all off at once.

Each kernel does per element exactly the floating-point operations of its numpy twin, so both
paths give the same numbers bit for bit (``tests/planning/test_kernels*.py``). ``cache=True``
keeps the compiled code beside its file (``__pycache__``), so that bench workers and later
runs load it instead of compiling again.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from companion.planning.dwa.kernels_fused import obstacle_pass, pick
from companion.planning.dwa.kernels_point import (choose, circle_clearance, heading_toward, near_mask,
                                                  open_clearance, polygon_clearance, sightline_depth)
from companion.planning.dwa.kernels_tick import heading_goals, obstacle_terms, sight_frame

__all__ = ["choose", "circle_clearance", "heading_goals", "heading_toward", "near_mask", "numpy_only",
           "obstacle_pass", "obstacle_terms", "open_clearance", "pick", "polygon_clearance", "sight_frame",
           "sightline_depth"]
_NAMES = ("circle_clearance", "polygon_clearance", "sightline_depth", "open_clearance", "near_mask",
          "heading_toward", "choose", "heading_goals", "obstacle_terms", "sight_frame", "obstacle_pass", "pick")


@contextmanager
def numpy_only() -> Iterator[None]:
    """Run the numpy kernels inside the block, numba or not (tests and benchmarks compare the two;
    it swaps module globals, so not while another thread plans)."""
    saved = {name: globals()[name] for name in _NAMES}
    globals().update(dict.fromkeys(_NAMES))
    try:
        yield
    finally:
        globals().update(saved)
