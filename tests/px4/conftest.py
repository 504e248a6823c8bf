"""The px4 tier: the companion flying real PX4 SITL (SIH physics), one instance per vehicle.

Every test here asks for the ``px4`` fixture (companion.testing.px4), which skips the test,
saying how to enable it, unless PX4_SITL_DIR or --px4-dir names a PX4 SITL build. PX4's ports are
fixed, so the tier runs on its own, one test at a time (docs/testing.md):

    PX4_SITL_DIR=../shared/px4-sih/sitl python -m pytest tests/px4 -p no:xdist
"""

from __future__ import annotations
