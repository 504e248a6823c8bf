"""The one numba setting every compiled twin of the DWA's critics uses (the ``*_jit`` modules,
imported only when numba is installed: the ``fast`` extra; :mod:`.backend` picks them).

Each compiled twin does, per element, exactly the floating-point operations of its numpy twin
in the same order (no fast-math, no contraction into fused multiply-adds), and both call the C
library's elementary functions (numpy's AVX-512 arctan2 does not: see :mod:`.libm`), so the two
give the same bits: ``tests/planning/test_kernels*.py`` checks each pair. What numpy does as a
matrix product stays in numpy (BLAS may fuse multiply-adds), and so do sums (numpy's pairwise
summation is not a loop's). What is saved is numpy's temporaries and its per-call overhead on
small arrays.

``cache=True`` keeps the compiled code beside its file (``__pycache__``), so that bench workers
and later runs load it instead of compiling again. Arguments of many arrays travel as plain
tuples in a fixed order (:meth:`.ObstacleSnapshot.arrays`, :attr:`.DwaConfig.choice_consts`):
numba types a plain tuple of arrays about as fast as separate arguments, a named tuple twice as
slowly.
"""

from __future__ import annotations

import numba





jit = numba.njit(cache=True, nogil=True, error_model="numpy")
inline = numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
