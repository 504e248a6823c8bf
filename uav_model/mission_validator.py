"""The validator of the published mission schema, as the loader runs it.

Two things differ from a plain Draft 2020-12 validator, neither in what it accepts beyond the
schema's own rules:

- ``number`` means a *finite* number: NaN and infinity fail the ``type`` keyword. JSON has
  neither, and the published schema cannot say so.
- Lists of points take a shortcut: when every item of a ``{"$ref": "#/$defs/point"}`` list is a
  plain point (``[x_m, y_m]`` or ``{lat_deg, lon_deg}``, finite, within the bounds that
  ``point_m`` and ``geo_point`` give), the list is valid without a descent per item. Any other
  list is validated item by item as usual, so its errors are the usual ones. The shortcut makes
  200 polygons of 256 vertices cost milliseconds instead of seconds.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from typing import Any

import jsonschema
from jsonschema import _keywords, _types

_POINT_REF = "#/$defs/point"


def _finite_number(checker: jsonschema.TypeChecker, instance: Any) -> bool:
    return _types.is_number(checker, instance) and (not isinstance(instance, float) or math.isfinite(instance))


def _bounded(lo: float, hi: float) -> Callable[[Any], bool]:
    def ok(v: Any) -> bool:
        return type(v) in (int, float) and lo <= v <= hi  # NaN fails both comparisons
    return ok


def _plain_point_test(defs: dict[str, Any]) -> Callable[[Any], bool]:
    """Whether a value is a point that ``#/$defs/point`` accepts, decided without jsonschema."""
    item = defs["point_m"]["items"]
    metres = _bounded(item["minimum"], item["maximum"])
    geo = defs["geo_point"]["properties"]
    lat = _bounded(geo["lat_deg"]["minimum"], geo["lat_deg"]["maximum"])
    lon = _bounded(geo["lon_deg"]["minimum"], geo["lon_deg"]["maximum"])
    keys = set(geo)

    def plain(p: Any) -> bool:
        if type(p) is list:
            return len(p) == 2 and metres(p[0]) and metres(p[1])
        return type(p) is dict and p.keys() == keys and lat(p["lat_deg"]) and lon(p["lon_deg"])
    return plain


def _items(plain: Callable[[Any], bool]):
    def items(validator, items, instance, schema) -> Iterator[jsonschema.ValidationError]:  # noqa: ANN001
        if (isinstance(items, dict) and items.get("$ref") == _POINT_REF and type(instance) is list
                and not schema.get("prefixItems") and all(plain(p) for p in instance)):
            return
        yield from _keywords.items(validator, items, instance, schema)
    return items


def mission_validator(schema: dict[str, Any]) -> jsonschema.protocols.Validator:
    """A validator for ``schema`` (the published mission schema) as the module doc describes."""
    base = jsonschema.Draft202012Validator
    cls = jsonschema.validators.extend(
        base, validators={"items": _items(_plain_point_test(schema["$defs"]))},
        type_checker=base.TYPE_CHECKER.redefine("number", _finite_number))
    return cls(schema)
