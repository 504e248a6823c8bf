"""The published JSON Schema for mission files, and the defaults it sets.

The schema is the one place a setting's default is written: the loader fills absent fields from
it, and the typed settings (:mod:`uav_model.mission_types`) take their dataclass defaults from it.
"""

from __future__ import annotations

import json
from functools import lru_cache
from importlib import resources
from typing import Any


@lru_cache(maxsize=1)
def mission_schema() -> dict[str, Any]:
    """The published JSON Schema for mission files (``companion schema`` prints it)."""
    text = resources.files("uav_model").joinpath("schema/mission.schema.json").read_text(encoding="utf-8")
    return json.loads(text)


def schema_default(section: str, *path: str) -> Any:
    """The schema's default of a field: ``("coordination", "hold_s_max")`` is a field of the
    ``coordination`` definition, ``("planner", "weights", "speed")`` a nested one, ``("plant",)``
    a top-level property. KeyError for a field the schema gives no default."""
    schema = mission_schema()
    node = schema["$defs"][section] if path else schema["properties"][section]
    for key in path:
        node = node["properties"][key]
    return node["default"]
