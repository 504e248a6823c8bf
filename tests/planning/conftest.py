"""Fixtures shared by the planning tests."""

from __future__ import annotations

import pytest

from companion.planning import astar_jit


@pytest.fixture(scope="module", params=["compiled", "python"])
def astar_search(request):
    """Run :func:`astar` on each search in turn: the compiled one (skipped without numba) and the
    Python one. Module-scoped so that Hypothesis tests may use it."""
    compiled = astar_jit.search
    if request.param == "compiled" and compiled is None:
        pytest.skip("needs the fast extra (numba): pip install -e '.[fast]'")
    astar_jit.search = compiled if request.param == "compiled" else None
    try:
        yield request.param
    finally:
        astar_jit.search = compiled
