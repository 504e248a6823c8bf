"""How a mission file's problems are reported: :class:`MissionError` names the file, the line and
the field path of each, and everything here finds those lines.

    MissionError
        raised for: unreadable file, YAML syntax, schema violation (unknown key, wrong type,
        out of range), dangling station names, duplicate names or ids, a station outside the
        area or inside an inflated obstacle. An unreachable goal is found by the planner and
        reported through :func:`mission_error` with the vehicle's field path.

A reason echoes at most :data:`ECHO_CHARS` characters of the value it is about (:func:`echo`),
and a combined error shows at most :data:`SHOWN_PROBLEMS` problems.
"""

from __future__ import annotations

import math
import reprlib
from typing import Any

import jsonschema
import yaml


ECHO_CHARS = 200
SHOWN_PROBLEMS = 40

_REPR = reprlib.Repr()
_REPR.maxlevel, _REPR.maxlist, _REPR.maxtuple, _REPR.maxdict, _REPR.maxset = 3, 6, 6, 6, 6
_REPR.maxstring, _REPR.maxother, _REPR.maxlong = ECHO_CHARS, ECHO_CHARS, 40


def echo(value: Any) -> str:
    """``repr(value)`` cut to at most :data:`ECHO_CHARS` characters, without building the whole
    repr of a huge value first."""
    return clip(_REPR.repr(value))


def clip(text: str) -> str:
    """``text`` cut to at most :data:`ECHO_CHARS` characters."""
    return text if len(text) <= ECHO_CHARS else text[:ECHO_CHARS - 3] + "..."


class MissionError(ValueError):
    """A mission file that cannot be flown. ``str()`` is one line: ``file:line: path: reason``."""

    def __init__(self, source: str, field_path: str, reason: str, line: int | None = None):
        self.source = source
        self.field_path = field_path
        self.reason = reason
        self.line = line
        self.problems: tuple[MissionError, ...] = (self,)
        where = f"{source}:{line}" if line is not None else source
        super().__init__(f"{where}: {field_path}: {reason}" if field_path else f"{where}: {reason}")

    @classmethod
    def of(cls, problems: list["MissionError"]) -> "MissionError":
        """One error for several problems, in file order: ``str()`` is one line per problem (the
        first :data:`SHOWN_PROBLEMS`, then one line counting the rest)."""
        ordered = sorted(problems, key=lambda e: (e.line is None, e.line or 0, e.field_path))
        first = ordered[0]
        combined = cls(first.source, first.field_path, first.reason, first.line)
        combined.problems = tuple(ordered)
        lines = [str(e) for e in ordered[:SHOWN_PROBLEMS]]
        if len(ordered) > SHOWN_PROBLEMS:
            lines.append(f"{first.source}: {len(ordered) - SHOWN_PROBLEMS} more problems not shown "
                         f"(the first {SHOWN_PROBLEMS} are)")
        combined.args = ("\n".join(lines),)
        return combined

    def __reduce__(self):
        return (_rebuild_error, (self.source, self.field_path, self.reason, self.line,
                                 tuple((e.field_path, e.reason, e.line) for e in self.problems)))


def _rebuild_error(source: str, field_path: str, reason: str, line: int | None,
                   problems: tuple[tuple[str, str, int | None], ...]) -> MissionError:
    if len(problems) <= 1:
        return MissionError(source, field_path, reason, line)
    return MissionError.of([MissionError(source, f, r, ln) for f, r, ln in problems])


def line_of(root: yaml.Node | None, path: list[Any]) -> int | None:
    """1-based line of the deepest YAML node that the path reaches."""
    node = root
    line = None if node is None else node.start_mark.line + 1
    for part in path:
        if isinstance(node, yaml.MappingNode):
            nxt = None
            for k, v in node.value:
                if k.value == str(part):
                    nxt = v
                    line = k.start_mark.line + 1
                    break
            node = nxt
        elif isinstance(node, yaml.SequenceNode) and isinstance(part, int) and part < len(node.value):
            node = node.value[part]
            line = node.start_mark.line + 1
        else:
            break
        if node is None:
            break
    return line


def dotted(path: list[Any] | tuple[Any, ...]) -> str:
    out = ""
    for part in path:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out


_BOUND_WORDS = {"minimum": "less than the minimum of", "maximum": "greater than the maximum of",
                "exclusiveMinimum": "less than or equal to the minimum of",
                "exclusiveMaximum": "greater than or equal to the maximum of"}
_DEGREES = {"lat_deg": "latitude", "lon_deg": "longitude"}


def innermost(err: jsonschema.ValidationError) -> jsonschema.ValidationError:
    """The error inside if/then and oneOf branches that names the real field: of a oneOf's
    branches, those whose type the value has (a ``{lat_deg, lon_deg}`` point with a NaN is a
    bad geodetic point, not a bad ``[x, y]``)."""
    while err.context:
        branches: dict[Any, list[jsonschema.ValidationError]] = {}
        for e in err.context:
            branches.setdefault(e.relative_schema_path[0] if e.relative_schema_path else None, []).append(e)
        typed = [e for errs in branches.values()
                 if not any(e.validator == "type" and not e.relative_path for e in errs) for e in errs]
        err = jsonschema.exceptions.best_match(typed or err.context)
    return err


def schema_reason(err: jsonschema.ValidationError) -> tuple[list[Any], str]:
    """Turn a jsonschema error into (field path, short reason) that a user can act on. Reasons
    are built here rather than taken from jsonschema, whose messages repeat the whole value."""
    path = list(err.absolute_path)
    kind, limit, value = err.validator, err.validator_value, err.instance
    if kind == "additionalProperties":
        allowed = sorted(err.schema.get("properties", {}))
        extra = [k for k in value if k not in err.schema.get("properties", {})] if isinstance(value, dict) else []
        if extra:
            hint = f"; allowed: {', '.join(allowed)}" if allowed else ""
            return path + [extra[0]], f"unknown key {echo(extra[0])}{hint}"
    if kind == "required":
        missing = [k for k in limit if isinstance(value, dict) and k not in value]
        return path, f"{echo(missing[0] if missing else limit[0])} is required"
    if kind == "type":
        if isinstance(value, float) and not math.isfinite(value):
            return path, f"{value!r} is not a finite number (NaN and infinity are refused everywhere)"
        return path, f"expected {limit}, got {type(value).__name__} {echo(value)}"
    if kind == "enum":
        return path, f"{echo(value)} is not one of {', '.join(map(str, limit))}"
    if kind in _BOUND_WORDS:
        name = _DEGREES.get(str(path[-1])) if path else None
        if name is not None:
            low, high = err.schema.get("minimum"), err.schema.get("maximum")
            return path, f"{name} {value:g} is out of range [{low:g}, {high:g}] degrees"
        return path, f"{echo(value)} is {_BOUND_WORDS[kind]} {limit:g}"
    if kind in ("maxItems", "maxProperties", "maxLength"):
        unit = "characters" if kind == "maxLength" else "items" if kind == "maxItems" else "entries"
        return path, f"{len(value)} {unit}, more than the limit of {limit}"
    if kind in ("minItems", "minProperties", "minLength"):
        unit = "characters" if kind == "minLength" else "items" if kind == "minItems" else "entries"
        return path, f"{len(value)} {unit}; at least {limit} needed"
    if kind == "pattern":
        return path, f"{echo(value)} does not match {limit}"
    return path, clip(err.message)


def mission_path(field_path: str) -> list[Any]:
    """``vehicles[1].goal`` as ``["vehicles", 1, "goal"]``."""
    parts: list[Any] = []
    for token in field_path.replace("[", ".[").split("."):
        if token:
            parts.append(int(token[1:-1]) if token.startswith("[") else token)
    return parts


def fail(source: str, root: yaml.Node | None, path: list[Any], reason: str) -> MissionError:
    return MissionError(source, dotted(path), reason, line_of(root, path))
