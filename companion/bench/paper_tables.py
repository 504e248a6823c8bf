"""The paper's Tables I-III: its numbers, and the reference mission varied as each table does.

``companion sweep table1|table2|table3`` flies each row headless and prints our flight times
beside the paper's (section VI.B).
"""

from __future__ import annotations

import dataclasses
import math

from uav_model.mission import Mission

# The paper's numbers (section VI.B), as printed: (row label, UAV a time s, UAV b time s).
PAPER_TABLES = {
    "table1": ("Table I: initial headings a / b = a - 180 deg",
               [("0", 519.0, 693.0), ("18", 495.0, 663.0), ("36", 492.0, 672.0), ("54", 492.0, 675.0),
                ("72", 490.5, 642.0), ("90", 489.0, 688.5)]),
    "table2": ("Table II: speed of UAV a (m/s)", [("10", 472.0, 640.0), ("20", 472.0, 558.0), ("30", 474.0, 476.0)]),
    "table3": ("Table III: |OA| (m), B on the same diagonal with |OB| = 1000 m",
               [("1000", 235.0, 234.0), ("2000", 349.0, 325.0), ("3000", 422.0, 535.0), ("4000", 521.0, 733.0)]),
}
TABLE3_OB_M = 1000.0  # see docs/results-reference.md: the |OB| that fits the paper's own a-times


def _with_vehicle(mission: Mission, name: str, **changes) -> Mission:
    vehicles = tuple(dataclasses.replace(v, **changes) if v.name == name else v for v in mission.vehicles)
    return dataclasses.replace(mission, vehicles=vehicles)


def table_missions(table: str, base: Mission) -> list[tuple[str, Mission]]:
    """The reference mission varied as the paper's table does: (row label, mission) pairs."""
    a, b = (v.name for v in base.by_priority[:2])
    rows = []
    for label, _, _ in PAPER_TABLES[table][1]:
        value = float(label)
        if table == "table1":
            m = _with_vehicle(_with_vehicle(base, a, initial_heading_deg=value), b, initial_heading_deg=value - 180.0)
        elif table == "table2":
            m = _with_vehicle(base, a, speed_m_s=value)
        else:
            m = _diagonal_mission(base, value, TABLE3_OB_M)
        rows.append((label, dataclasses.replace(m, name=f"{base.name}_{table}_{label}")))
    return rows


def _diagonal_mission(base: Mission, oa_m: float, ob_m: float) -> Mission:
    """A at the origin, the (single) obstacle's centre at |OA| and B at |OA| + |OB| on the
    45 deg diagonal; the area is the square with A and B at opposite corners."""
    from shapely import affinity

    from uav_model.world import World
    (obstacle,) = base.world.obstacles
    a, b = (v.name for v in base.by_priority[:2])
    k = 1.0 / math.sqrt(2.0)
    o_xy = (oa_m * k, oa_m * k)
    side = (oa_m + ob_m) * k
    moved = dataclasses.replace(obstacle, center=o_xy, footprint=affinity.translate(
        obstacle.footprint, o_xy[0] - obstacle.center[0], o_xy[1] - obstacle.center[1]))
    world = World(0.0, 0.0, side, side, base.world.geofence_margin_m, (moved,))
    start_a = base.vehicle(a).start
    start_b = base.vehicle(b).start
    stations = {start_a: (0.0, 0.0), start_b: (side, side)}
    m = dataclasses.replace(base, world=world, stations=stations)
    m = _with_vehicle(m, a, start_enu_m=(0.0, 0.0), goal_enu_m=(side, side))
    return _with_vehicle(m, b, start_enu_m=(side, side), goal_enu_m=(0.0, 0.0))
