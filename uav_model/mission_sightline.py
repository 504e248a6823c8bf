"""``sightline.pairs``: the pairs of vehicles whose sight line must stay blocked, checked and typed.

Each pair names two vehicles of the file. Refused, each with its own line: a name that is no
vehicle of the file, a vehicle paired with itself, and a pair named twice (in either order). A
valid pair is typed as (higher priority, lower priority): the lower one hides from the higher,
as the paper's prioritised pair does (see :meth:`uav_model.mission_types.Mission.hides_from`).
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Sequence
from typing import Any

from uav_model.mission_errors import clip, echo
from uav_model.mission_types import VehicleSpec


def assigned_pairs(raw: dict[str, Any] | None, vehicles: Sequence[VehicleSpec], named: Collection[Any],
                   add: Callable[[list[Any], str], None]) -> tuple[tuple[str, str], ...] | None:
    """The pairs ``raw`` (the file's ``sightline`` mapping, schema-valid) assigns, or None when
    the file has no ``sightline`` section; every problem goes to ``add(path, reason)``.
    ``vehicles``: the valid vehicles; ``named``: every name the file gives a vehicle (a pair
    naming one the schema refused is skipped, its vehicle's problem already reported)."""
    if raw is None:
        return None
    rank = {v.name: k for k, v in enumerate(sorted(vehicles, key=lambda v: (v.priority, v.index)))}
    known = clip(", ".join(rank))
    seen: dict[frozenset[str], int] = {}
    pairs: list[tuple[str, str]] = []
    for i, pair in enumerate(raw["pairs"]):
        path = ["sightline", "pairs", i]
        unknown = [(j, name) for j, name in enumerate(pair) if name not in rank]
        for j, name in unknown:
            if name not in named:
                add(path + [j], f"unknown vehicle {echo(name)}; vehicles are {known}")
        if unknown:
            continue
        a, b = pair
        if a == b:
            add(path, f"vehicle {echo(a)} is paired with itself; a pair names two vehicles")
            continue
        key = frozenset(pair)
        if key in seen:
            add(path, f"duplicate pair {a}-{b} (already sightline.pairs[{seen[key]}])")
            continue
        seen[key] = i
        pairs.append((a, b) if rank[a] < rank[b] else (b, a))
    return tuple(pairs)
