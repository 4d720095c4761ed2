"""YAML loading that remembers where every value came from (file:line:column).

Procedures and configs are validated against their schema with errors located in the source
file, so the loader keeps a :class:`Node` per value. Loading uses PyYAML's safe composer: no tags,
no Python objects, nothing executes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

import yaml

from bench.errors import InputError, Location
from bench.inputs import YAML_LIMIT_BYTES, read_input_bytes


@dataclass
class Node:
    """A YAML value with its location. ``value`` is a str/int/float/bool/None, list[Node] or dict[str, Node]."""

    value: Any
    location: Location
    key_locations: dict[str, Location] = field(default_factory=dict)

    def __repr__(self) -> str:  # messages quoting a list or mapping show its values, not Node objects
        return repr(self.plain())

    def plain(self) -> Any:
        """The value with all nested Nodes unwrapped to plain Python."""
        if isinstance(self.value, list):
            return [n.plain() for n in self.value]
        if isinstance(self.value, dict):
            return {k: n.plain() for k, n in self.value.items()}
        return self.value


@dataclass
class Source:
    """A loaded YAML document: its path, exact text and root node."""

    path: Path
    text: str
    root: Node


def _loc(path: str, mark: yaml.Mark) -> Location:
    return Location(path, mark.line + 1, mark.column + 1)


_SAFE = yaml.SafeLoader
_PLAIN_TAGS = ("tag:yaml.org,2002:seq", "tag:yaml.org,2002:map")
MAX_VALUES = 100_000
"""Most values (scalars, lists, mappings) a document may hold once its aliases are expanded: a
few aliases of aliases would otherwise expand into billions of values."""
MAX_FLOAT = float.fromhex("0x1.fffffffffffffp+1023")


class _Budget:
    """Values left to convert, and the collection nodes being converted (to catch an alias of itself)."""

    def __init__(self) -> None:
        self.left = MAX_VALUES
        self.active: set[int] = set()


def _convert(node: yaml.Node, path: str, budget: _Budget) -> Node:
    loc = _loc(path, node.start_mark)
    budget.left -= 1
    if budget.left < 0:
        raise InputError(f"the document holds more than {MAX_VALUES} values (aliases expanding too far?)", loc)
    if isinstance(node, yaml.ScalarNode):
        # Resolve the scalar the way SafeLoader would (int, float, bool, null, str).
        loader = _SAFE("")
        try:
            value = loader.construct_object(node, deep=True)
        except Exception as exc:  # noqa: BLE001 - an explicit tag on text it does not fit (!!int abc, !!timestamp x) raises anything
            raise InputError(f"cannot read value: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}", loc) from None
        finally:
            loader.dispose()
        if isinstance(value, int) and not isinstance(value, bool) and abs(value) > MAX_FLOAT:
            raise InputError(f"number {node.value[:20]}{'...' if len(node.value) > 20 else ''} is too large", loc)
        if not isinstance(value, (str, int, float, bool, type(None))):
            value = str(node.value)  # timestamps, binary: keep the text, schema decides
        return Node(value, loc)
    if node.tag not in _PLAIN_TAGS:
        raise InputError(f"YAML tag {node.tag!r} is not allowed (plain lists and mappings only)", loc)
    if id(node) in budget.active:
        raise InputError("an alias refers to the list or mapping that contains it", loc)
    budget.active.add(id(node))
    try:
        if isinstance(node, yaml.SequenceNode):
            return Node([_convert(n, path, budget) for n in node.value], loc)
        if isinstance(node, yaml.MappingNode):
            out: dict[str, Node] = {}
            keys: dict[str, Location] = {}
            for key_node, value_node in node.value:
                kloc = _loc(path, key_node.start_mark)
                if not isinstance(key_node, yaml.ScalarNode):
                    raise InputError("mapping keys must be plain names", kloc)
                _convert(key_node, path, budget)  # refuses tags SafeLoader refuses (!!python/...)
                key = str(key_node.value)
                if not key.isprintable():  # a line break or control character would break the one-line messages
                    raise InputError(f"mapping key {key!r} is not a plain name", kloc)
                if key in out:
                    raise InputError(f"duplicate key {key!r} (first at line {keys[key].line})", kloc, key)
                out[key] = _convert(value_node, path, budget)
                keys[key] = kloc
            return Node(out, loc, keys)
    finally:
        budget.active.discard(id(node))
    raise InputError("unsupported YAML node", loc)


def load_yaml(path: str | Path, what: str = "file") -> Source:
    """Read and parse ``path``; any problem is an :class:`InputError` located in the file."""
    p = Path(path)
    data = read_input_bytes(p, limit_bytes=YAML_LIMIT_BYTES, what=what)  # regular files of at most 1 MiB
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise InputError(f"cannot read {what}: byte 0x{data[exc.start]:02x} is not UTF-8 text", Location(p, line)) from None
    text = text.replace("\r\n", "\n").replace("\r", "\n")  # universal newlines, as text-mode reading
    return parse_yaml(text, str(p), what)


def parse_yaml(text: str, path: str, what: str = "file") -> Source:
    """Parse YAML ``text`` (from ``path``, used in messages) into a located :class:`Node` tree."""
    try:
        nodes = list(yaml.compose_all(text, Loader=_SAFE))
    except RecursionError:
        raise InputError("not valid YAML: lists or mappings nested too deeply", Location(path)) from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        loc = _loc(path, mark) if mark else Location(path)
        raise InputError(f"not valid YAML: {exc.problem or exc.context}", loc) from None
    except yaml.reader.ReaderError as exc:  # a character YAML does not allow (NUL, a control character)
        line = text.count("\n", 0, exc.position) + 1
        column = exc.position - (text.rfind("\n", 0, exc.position) + 1) + 1
        char = f"#x{exc.character:04x}" if isinstance(exc.character, int) else repr(exc.character)
        raise InputError(f"not valid YAML: unacceptable character {char}: {exc.reason}", Location(path, line, column)) from None
    except yaml.YAMLError as exc:
        raise InputError(f"not valid YAML: {' '.join(str(exc).split())}", Location(path)) from None
    if len(nodes) != 1 or nodes[0] is None:
        raise InputError(f"expected exactly one YAML document in the {what}", Location(path, 1, 1))
    try:
        root = _convert(nodes[0], path, _Budget())
    except RecursionError:
        raise InputError("lists or mappings nested too deeply", Location(path)) from None
    if not isinstance(root.value, dict):
        raise InputError(f"the {what} must be a mapping at top level", root.location)
    return Source(Path(path), text, root)


class Fields:
    """Typed, located access to a mapping node; collects unknown-key errors.

    >>> f = Fields(node, "configure step")  # doctest: +SKIP
    >>> f.required("instrument", str)        # doctest: +SKIP
    """

    def __init__(self, node: Node, what: str, errors: list[InputError]):
        self.node = node
        self.what = what
        self.errors = errors
        if not isinstance(node.value, dict):
            errors.append(InputError(f"{what} must be a mapping", node.location))
            self.map: dict[str, Node] = {}
        else:
            self.map = node.value
        self.used: set[str] = set()

    def key_location(self, key: str) -> Location:
        return self.node.key_locations.get(key, self.node.location)

    def get(self, key: str, types: type | tuple[type, ...], default: Any = None, required: bool = False) -> Any:
        """The plain value at ``key`` if it has one of ``types``; else record an error and return ``default``."""
        self.used.add(key)
        if key not in self.map:
            if required:
                self.errors.append(InputError(f"missing required field in {self.what}", self.node.location, key))
            return default
        n = self.map[key]
        value = n.value
        if isinstance(value, bool) and bool not in (types if isinstance(types, tuple) else (types,)):
            ok = False
        else:
            ok = isinstance(value, types) if not isinstance(value, (list, dict)) else (
                (list in _as_tuple(types) and isinstance(value, list)) or (dict in _as_tuple(types) and isinstance(value, dict))
            )
        if not ok:
            names = " or ".join(t.__name__ for t in _as_tuple(types))
            self.errors.append(InputError(f"expected {names}, got {_describe(value)}", n.location, key))
            return default
        return n.plain() if isinstance(value, (list, dict)) else value

    def node_at(self, key: str) -> Node | None:
        self.used.add(key)
        return self.map.get(key)

    def check_unknown(self, allowed_extra: Iterator[str] = ()) -> None:
        """Record an error for each key nobody asked for."""
        known = self.used | set(allowed_extra)
        for key in self.map:
            if key not in known:
                expected = ", ".join(sorted(self.used)) or "no fields"
                self.errors.append(
                    InputError(f"unknown field in {self.what} (expected one of: {expected})", self.key_location(key), key)
                )


def _as_tuple(types: type | tuple[type, ...]) -> tuple[type, ...]:
    return types if isinstance(types, tuple) else (types,)


def _describe(value: Any) -> str:
    if isinstance(value, list):
        return "a list"
    if isinstance(value, dict):
        return "a mapping"
    if value is None:
        return "nothing"
    return f"{type(value).__name__} {value!r}"
