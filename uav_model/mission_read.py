"""Reading a mission file without trusting it: bounded bytes, bounded YAML, finite numbers.

Every limit is named in the error it raises, so a user knows what to change:

- the file: a regular file (not a directory, a fifo or a device) of at most
  ``MAX_FILE_BYTES`` (:mod:`mission_limits`), UTF-8 text;
- the YAML: nesting at most ``MAX_DEPTH`` deep and at most ``MAX_NODES`` values, where an
  alias counts as the whole value it repeats. Both are counted while the document is composed,
  before anything is expanded, so an alias bomb costs what its text costs;
- JSON (``companion import``): the same size, depth and node limits, and no ``NaN`` or
  ``Infinity``.

An error echoes at most ``ECHO_CHARS`` characters of a value (:func:`mission_errors.echo`).
"""

from __future__ import annotations

import json
import math
import os
import re
import stat
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml
from yaml.composer import Composer
from yaml.constructor import SafeConstructor
from yaml.resolver import Resolver

from uav_model.mission_errors import MissionError, clip, echo, line_of, mission_path
from uav_model.mission_limits import MAX_DEPTH, MAX_FILE_BYTES, MAX_NODES

if TYPE_CHECKING:
    from uav_model.mission_types import Mission

__all__ = ["BoundedLoader", "finite", "load_json", "load_yaml", "mission_error", "read_text"]


def finite(value: Any) -> float | None:
    """``value`` as a float when it is a finite real number (not a bool), else None."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    try:
        out = float(value)
    except OverflowError:  # an int beyond a float's range
        return None
    return out if math.isfinite(out) else None


def read_text(path: str | Path) -> str:
    """A mission file's text. Raises MissionError for a missing, unreadable, non-regular,
    oversized or non-UTF-8 file: never blocks on a fifo, never reads more than the limit."""
    source = str(path)
    try:
        fd = os.open(source, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        raise MissionError(source, "", "file not found") from None
    except OSError as exc:
        raise MissionError(source, "", f"cannot read file: {exc.strerror or exc}") from None
    try:
        mode = os.fstat(fd).st_mode
        if stat.S_ISDIR(mode):
            raise MissionError(source, "", "is a directory, not a mission file")
        if not stat.S_ISREG(mode):
            raise MissionError(source, "", "not a regular file (a fifo, socket or device); give a mission file")
        data = _read_upto(fd, MAX_FILE_BYTES + 1)
    except OSError as exc:
        raise MissionError(source, "", f"cannot read file: {exc.strerror or exc}") from None
    finally:
        os.close(fd)
    if len(data) > MAX_FILE_BYTES:
        raise MissionError(source, "", f"file is larger than the limit of {MAX_FILE_BYTES // (1024 * 1024)} MiB")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[:exc.start].count(b"\n") + 1
        raise MissionError(source, "", f"not UTF-8 text (byte 0x{data[exc.start]:02x} at offset {exc.start})",
                           line) from None


def _read_upto(fd: int, limit: int) -> bytes:
    chunks: list[bytes] = []
    size = 0
    while size < limit:
        chunk = os.read(fd, min(1 << 20, limit - size))
        if not chunk:
            break
        chunks.append(chunk)
        size += len(chunk)
    return b"".join(chunks)


def _too_big(what: str, mark: Any) -> yaml.YAMLError:
    return yaml.MarkedYAMLError(problem=what, problem_mark=mark)


class _Counting:
    """Composer hooks: depth and expanded size of every node, checked as each one is composed."""

    _depth: int
    _nodes: int
    _sizes: dict[str, int]

    def _start_counting(self) -> None:
        self._depth, self._nodes, self._sizes = 0, 0, {}

    def compose_node(self, parent, index):  # noqa: ANN001 (PyYAML's signature)
        event = self.peek_event()
        if isinstance(event, yaml.AliasEvent):
            self._nodes += self._sizes.get(event.anchor, 1)
            if self._nodes > MAX_NODES:
                raise _too_big(f"more than {MAX_NODES} values once aliases are expanded (the limit)",
                               event.start_mark)
            return Composer.compose_node(self, parent, index)
        self._depth += 1
        if self._depth > MAX_DEPTH:
            raise _too_big(f"nested more than {MAX_DEPTH} levels deep (the limit)", event.start_mark)
        before = self._nodes
        node = Composer.compose_node(self, parent, index)
        self._depth -= 1
        self._nodes += 1
        if self._nodes > MAX_NODES:
            raise _too_big(f"more than {MAX_NODES} values (the limit)", event.start_mark)
        anchor = getattr(event, "anchor", None)
        if anchor is not None:
            self._sizes[anchor] = self._nodes - before
        return node

    def construct_mapping(self, node, deep=False):  # noqa: ANN001 (PyYAML's signature)
        """Refuse duplicate keys (silently dropping one is lost data) and keys that are not text."""
        if isinstance(node, yaml.MappingNode):
            self.flatten_mapping(node)
        seen: set[Any] = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            if not isinstance(key, str):
                raise yaml.constructor.ConstructorError(
                    None, None, f"key {echo(key)} is not text; quote it", key_node.start_mark)
            if key in seen:
                raise yaml.constructor.ConstructorError(None, None, f"duplicate key {key!r}", key_node.start_mark)
            seen.add(key)
        return SafeConstructor.construct_mapping(self, node, deep=deep)


if getattr(yaml, "__with_libyaml__", False):
    from yaml._yaml import CParser

    class BoundedLoader(_Counting, CParser, SafeConstructor, Resolver):
        """libyaml's parser (its events), PyYAML's composer with the limits, the safe constructor."""

        def __init__(self, stream: str):
            CParser.__init__(self, stream)
            SafeConstructor.__init__(self)
            Resolver.__init__(self)
            self.anchors = {}
            self._start_counting()

        get_single_node = Composer.get_single_node
        compose_document = Composer.compose_document
        compose_scalar_node = Composer.compose_scalar_node
        compose_sequence_node = Composer.compose_sequence_node
        compose_mapping_node = Composer.compose_mapping_node
else:  # pragma: no cover (PyYAML built without libyaml)
    class BoundedLoader(_Counting, yaml.SafeLoader):  # type: ignore[no-redef]
        """PyYAML's safe loader with the limits."""

        def __init__(self, stream: str):
            yaml.SafeLoader.__init__(self, stream)
            self._start_counting()

BoundedLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, BoundedLoader.construct_mapping)
# YAML 1.1 reads 1e3 (no dot) as a string; a user, JSON and YAML 1.2 mean a number.
BoundedLoader.add_implicit_resolver("tag:yaml.org,2002:float",
                                    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
                                    list("-+0123456789."))


def load_yaml(text: str, source: str) -> tuple[Any, yaml.Node | None]:
    """(document, its node tree for line numbers) of YAML text within the limits."""
    loader = BoundedLoader(text)
    try:
        root = loader.get_single_node()
        data = None if root is None else loader.construct_document(root)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = mark.line + 1 if mark is not None else None
        problem = getattr(exc, "problem", None) or str(exc)
        if "maximum nesting depth" in problem:  # libyaml's own guard, met before ours in flow style
            problem = f"nested more than {MAX_DEPTH} levels deep (the limit)"
        raise MissionError(source, "", f"YAML syntax: {clip(problem)}", line) from None
    finally:
        loader.dispose()
    return data, root


class _NotFinite(ValueError):
    pass


def _no_constant(token: str) -> float:
    raise _NotFinite(token)


def _finite_float(token: str) -> float:
    value = float(token)
    if not math.isfinite(value):
        raise _NotFinite(token)
    return value


def load_json(text: str, source: str) -> Any:
    """A JSON document within the limits; NaN, Infinity and numbers beyond a float's range refused."""
    try:
        doc = json.loads(text, parse_constant=_no_constant, parse_float=_finite_float)
    except json.JSONDecodeError as exc:
        raise MissionError(source, "", f"not JSON: {exc.msg}", exc.lineno) from None
    except _NotFinite as exc:
        token = str(exc)
        line = text[:max(text.find(token), 0)].count("\n") + 1
        raise MissionError(source, "", f"{clip(token)} is not a finite number", line) from None
    except RecursionError:
        raise MissionError(source, "", f"nested more than {MAX_DEPTH} levels deep (the limit)") from None
    _check_json_size(doc, source)
    return doc


def _check_json_size(doc: Any, source: str) -> None:
    stack: list[tuple[Any, int]] = [(doc, 1)]
    nodes = 0
    while stack:
        value, depth = stack.pop()
        nodes += 1
        if depth > MAX_DEPTH:
            raise MissionError(source, "", f"nested more than {MAX_DEPTH} levels deep (the limit)")
        if nodes > MAX_NODES:
            raise MissionError(source, "", f"more than {MAX_NODES} values (the limit)")
        if isinstance(value, dict):
            stack.extend((v, depth + 1) for v in value.values())
        elif isinstance(value, list):
            stack.extend((v, depth + 1) for v in value)


def mission_error(mission_or_source: Mission | str, field_path: str, reason: str,
                  root: yaml.Node | None = None) -> MissionError:
    """A MissionError for a semantic problem found after loading (e.g. an unreachable goal), at
    its field's line when the file can still be read."""
    source = mission_or_source if isinstance(mission_or_source, str) else mission_or_source.source
    if root is None:
        try:
            _, root = load_yaml(read_text(source), source)
        except MissionError:  # not a file (a generated mission), or gone since
            root = None
    return MissionError(source, field_path, reason, None if root is None else line_of(root, mission_path(field_path)))
