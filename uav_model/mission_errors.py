"""How a mission file's problems are reported: :class:`MissionError` names the file, the line and
the field path of each, and everything here finds those lines.

    MissionError
        raised for: unreadable file, YAML syntax, schema violation (unknown key, wrong type,
        out of range), dangling station names, duplicate names or ids, a station outside the
        area or inside an inflated obstacle. An unreachable goal is found by the planner and
        reported through :func:`mission_error` with the vehicle's field path.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import jsonschema
import yaml

if TYPE_CHECKING:
    from uav_model.mission_types import Mission


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
        """One error for several problems, in file order: ``str()`` is one line per problem."""
        ordered = sorted(problems, key=lambda e: (e.line is None, e.line or 0, e.field_path))
        first = ordered[0]
        combined = cls(first.source, first.field_path, first.reason, first.line)
        combined.problems = tuple(ordered)
        combined.args = ("\n".join(str(e) for e in ordered),)
        return combined

    def __reduce__(self):
        return (_rebuild_error, (self.source, self.field_path, self.reason, self.line,
                                 tuple((e.field_path, e.reason, e.line) for e in self.problems)))


def _rebuild_error(source: str, field_path: str, reason: str, line: int | None,
                   problems: tuple[tuple[str, str, int | None], ...]) -> MissionError:
    if len(problems) <= 1:
        return MissionError(source, field_path, reason, line)
    return MissionError.of([MissionError(source, f, r, ln) for f, r, ln in problems])


class StrictLoader(yaml.SafeLoader):
    """SafeLoader that refuses duplicate keys (silently dropping one is lost data)."""


def _construct_mapping(loader: StrictLoader, node: yaml.MappingNode, deep: bool = False) -> dict:
    seen: dict[Any, yaml.Node] = {}
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        if key in seen:
            raise yaml.constructor.ConstructorError(
                None, None, f"duplicate key {key!r}", key_node.start_mark)
        seen[key] = key_node
    return yaml.SafeLoader.construct_mapping(loader, node, deep=deep)


StrictLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


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


def schema_reason(err: jsonschema.ValidationError) -> tuple[list[Any], str]:
    """Turn a jsonschema error into (field path, short reason) that a user can act on."""
    path = list(err.absolute_path)
    if err.validator == "additionalProperties":
        allowed = sorted(err.schema.get("properties", {}))
        extra = [k for k in err.instance if k not in err.schema.get("properties", {})] if isinstance(err.instance, dict) else []
        if extra:
            hint = f"; allowed: {', '.join(allowed)}" if allowed else ""
            return path + [extra[0]], f"unknown key {extra[0]!r}{hint}"
    if err.validator == "required":
        return path, err.message.replace("is a required property", "is required")
    if err.validator == "type":
        return path, f"expected {err.validator_value}, got {type(err.instance).__name__} {err.instance!r}"
    if err.validator == "enum":
        return path, f"{err.instance!r} is not one of {', '.join(map(str, err.validator_value))}"
    return path, err.message


def mission_error(mission_or_source: Mission | str, field_path: str, reason: str,
                  root: yaml.Node | None = None) -> MissionError:
    """A MissionError for a semantic problem found after loading (e.g. an unreachable goal)."""
    source = mission_or_source if isinstance(mission_or_source, str) else mission_or_source.source
    line = None
    if root is None:
        try:
            root = yaml.compose(Path(source).read_text(encoding="utf-8"), Loader=yaml.SafeLoader)
        except (OSError, yaml.YAMLError, UnicodeDecodeError):
            root = None
    if root is not None:
        parts: list[Any] = []
        for token in field_path.replace("[", ".[").split("."):
            if not token:
                continue
            parts.append(int(token[1:-1]) if token.startswith("[") else token)
        line = line_of(root, parts)
    return MissionError(source, field_path, reason, line)


def fail(source: str, root: yaml.Node | None, path: list[Any], reason: str) -> MissionError:
    return MissionError(source, dotted(path), reason, line_of(root, path))
