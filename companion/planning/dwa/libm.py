"""arctan2 with the C library's bits on every CPU.

The compiled kernels (numba) call the C library's ``atan2`` per element. numpy's own ``arctan2``
does too on most CPUs, but where numpy dispatches its AVX-512 loops (``X86_V4``, e.g. AMD Zen 4/5,
Intel Ice Lake and later) it uses a vectorised approximation that differs in the last bit for
about one input in thirteen. The heading critic's numpy path would then score rollouts a bit
differently from the compiled path, and a tie could go the other way. So the numpy path asks
numpy once whether it agrees with the C library here, and if it does not, calls the C library
element by element (``math.atan2`` is the C library's; ~0.1 us per element, on a few hundred
elements a tick, and only on such CPUs without the ``fast`` extra)."""

from __future__ import annotations

import math

import numpy as np

_ELEMENTWISE = np.frompyfunc(math.atan2, 2, 1)


def _numpy_agrees() -> bool:
    """Whether numpy's arctan2 gives the C library's bits on this CPU (4,096 points around a UAV;
    where it differs, it differs on hundreds of them)."""
    y, x = np.random.default_rng(0).uniform(-1e3, 1e3, (2, 4096))
    return bool(np.array_equal(np.arctan2(y, x), _ELEMENTWISE(y, x).astype(np.float64)))


def _elementwise(y, x) -> np.ndarray:
    """arctan2 by the C library, element by element, broadcast as numpy's."""
    return np.asarray(_ELEMENTWISE(y, x), dtype=np.float64)


arctan2 = np.arctan2 if _numpy_agrees() else _elementwise
