"""Typed access to a YAML document that keeps line numbers, for configuration files.

:func:`read_yaml` parses a file into :class:`Node` values (Python value + 1-based line). A :class:`Section`
reads the keys of one mapping with type and range checks and, in :meth:`Section.finish`, rejects keys
nobody asked for (a key of :data:`REMOVED_KEYS` with the reason it went). Every problem raises
:class:`~pivotd.errors.ConfigError` as
``<file>:<line>: <key.path>: <what is wrong>``.
"""

from __future__ import annotations

import difflib
import math
import re
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from pivotd.errors import ConfigError

_MISSING = object()
_YAML12_FLOAT = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+")


@dataclass(frozen=True)
class Node:
    """A YAML value: scalars as Python values, mappings as dict[str, Node], sequences as list[Node]."""

    value: Any
    line: int | None


#: Keys that existed once, by dotted path, and why they went: reading one is an unknown-key error with this hint.
SPREAD_WEIGHTS_HINT = "removed: measured and not kept, see docs/experiments/spread-weights.md"
REMOVED_KEYS: dict[str, str] = {
    "planner.spread_cell_deg": SPREAD_WEIGHTS_HINT,
    "planner.spread_saturation": SPREAD_WEIGHTS_HINT,
    "planner.spread_depth_ratio": SPREAD_WEIGHTS_HINT,
}

MAX_DEPTH = 64  # nesting levels of mappings and sequences
MAX_NODES = 100_000  # values after alias expansion (a config has a few hundred)
MAX_BYTES = 1 << 20  # size of a config file


class _BoundedLoader(yaml.SafeLoader):
    """SafeLoader refusing documents nested deeper than MAX_DEPTH: flow collections in the scanner, any node
    in the composer (which recurses per level)."""

    _depth = 0

    def fetch_flow_collection_start(self, TokenClass: type) -> None:
        # The scanner looks ahead to the end of a flow collection (it may be a key), quadratically in its
        # depth: refuse deep flow nesting while scanning, before the composer sees anything.
        if self.flow_level >= MAX_DEPTH:
            raise _LimitError(self.line + 1, f"nesting deeper than {MAX_DEPTH} levels")
        super().fetch_flow_collection_start(TokenClass)

    def compose_node(self, parent: yaml.Node | None, index: Any) -> yaml.Node | None:
        if self._depth >= MAX_DEPTH:
            mark = self.peek_event().start_mark
            raise _LimitError(mark.line + 1, f"nesting deeper than {MAX_DEPTH} levels")
        self._depth += 1
        try:
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


class _LimitError(Exception):
    def __init__(self, line: int, problem: str) -> None:
        super().__init__(problem)
        self.line = line
        self.problem = problem


class _Converter:
    """Turns a composed YAML graph into :class:`Node` values, expanding aliases with a budget.

    An alias that refers to one of its own enclosing nodes (a recursive alias) and a document that
    expands to more than MAX_NODES values (an alias "bomb") are refused.
    """

    def __init__(self, file: Path) -> None:
        self.file = file
        self.constructor = yaml.constructor.SafeConstructor()
        self.count = 0
        self.open: set[int] = set()  # ids of the nodes being converted (the current path from the root)

    def convert(self, node: yaml.Node, path: str = "") -> Node:
        """``node`` (at dotted key ``path``, "" for the top level) as a :class:`Node`."""
        line = node.start_mark.line + 1
        self.count += 1
        if self.count > MAX_NODES:
            raise _LimitError(line, f"more than {MAX_NODES} values after expanding aliases")
        if not isinstance(node, yaml.MappingNode | yaml.SequenceNode):
            try:
                return Node(self.constructor.construct_object(node, deep=True), line)
            except (ValueError, OverflowError) as exc:  # a timestamp out of range, an integer of >4300 digits
                where = f"{path}: " if path else ""
                raise ConfigError(f"{self.file}:{line}: {where}YAML value cannot be read "
                                  f"({type(exc).__name__}: {exc})") from None
        if id(node) in self.open:
            raise _LimitError(line, "recursive alias (a node that contains itself)")
        self.open.add(id(node))
        try:
            if isinstance(node, yaml.SequenceNode):
                return Node([self.convert(item, f"{path}[{i}]") for i, item in enumerate(node.value)], line)
            return Node(self._mapping(node, path), line)
        finally:
            self.open.discard(id(node))

    def _mapping(self, node: yaml.MappingNode, path: str) -> dict[str, Node]:
        out: dict[str, Node] = {}
        for key_node, value_node in node.value:
            key_line = key_node.start_mark.line + 1
            key = self.constructor.construct_object(key_node) if isinstance(key_node, yaml.ScalarNode) else None
            if not isinstance(key, str):
                shown = repr(key) if isinstance(key_node, yaml.ScalarNode) else f"({key_node.id})"
                raise ConfigError(f"{self.file}:{key_line}: key {shown} is not a string")
            if key in out:
                raise ConfigError(f"{self.file}:{key_line}: {key}: duplicate key")
            value = self.convert(value_node, f"{path}.{key}" if path else key)
            out[key] = Node(value.value, key_line)  # errors point at the key's line
        return out


def read_yaml(path: Path) -> Node:
    """Parse one YAML document into a :class:`Node` tree; an empty file gives an empty mapping.

    Bounded: at most MAX_BYTES of text, MAX_DEPTH levels of nesting and MAX_NODES values after alias
    expansion; recursive aliases are refused. Every problem is a one-line ConfigError naming the file.
    """
    try:
        size = path.stat().st_size
        if size > MAX_BYTES:
            raise ConfigError(f"{path}: config file is {size} bytes, more than the {MAX_BYTES} a config may have")
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such config file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read config file ({exc})") from None
    try:
        loader = _BoundedLoader(text)
        try:
            root = loader.get_single_node()
        finally:
            loader.dispose()
        if root is None:
            return Node({}, 1)
        return _Converter(path).convert(root)
    except _LimitError as exc:
        raise ConfigError(f"{path}:{exc.line}: YAML refused: {exc.problem}") from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f"{path}:{mark.line + 1}" if mark is not None else str(path)
        raise ConfigError(f"{where}: YAML syntax error: {exc.problem or exc}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: YAML error: {exc}") from None
    except (RecursionError, ValueError, OverflowError) as exc:  # e.g. a timestamp scalar out of range
        raise ConfigError(f"{path}: YAML value cannot be read ({type(exc).__name__}: {exc})") from None


class Section:
    """Typed reader of one YAML mapping at dotted key ``path`` in ``file``."""

    def __init__(self, file: Path, node: Node | None, path: str = "") -> None:
        self.file = file
        self.path = path
        self.line = node.line if node is not None else None
        if node is not None and not isinstance(node.value, dict):
            raise self.error_at(node.line, path or "(top level)", f"must be a mapping, got {_kind(node.value)}")
        self._items: dict[str, Node] = dict(node.value) if node is not None else {}
        self._used: set[str] = set()

    # -------------------------------------------------------------- errors
    def key_path(self, key: str) -> str:
        return f"{self.path}.{key}" if self.path else key

    def error_at(self, line: int | None, key_path: str, message: str) -> ConfigError:
        where = f"{self.file}:{line}" if line is not None else str(self.file)
        return ConfigError(f"{where}: {key_path}: {message}")

    def error(self, key: str, message: str) -> ConfigError:
        """A ConfigError for ``key`` of this section, at the key's line (or the section's)."""
        node = self._items.get(key)
        return self.error_at(node.line if node is not None else self.line, self.key_path(key), message)

    # -------------------------------------------------------------- access
    def has(self, key: str) -> bool:
        return key in self._items and self._items[key].value is not None

    def section(self, key: str) -> Section:
        """The sub-mapping at ``key`` (empty when absent or null)."""
        self._used.add(key)
        node = self._items.get(key)
        if node is not None and node.value is None:
            node = None
        return Section(self.file, node, self.key_path(key))

    def _raw(self, key: str, default: Any) -> tuple[Any, bool]:
        self._used.add(key)
        node = self._items.get(key)
        if node is None or node.value is None:
            if default is _MISSING:
                raise self.error(key, "required key is missing")
            return default, False
        return node.value, True

    def number(
        self,
        key: str,
        default: Any = _MISSING,
        *,
        min: float | None = None,
        max: float | None = None,
        min_open: bool = False,
        max_open: bool = False,
        integer: bool = False,
    ) -> Any:
        """A finite number (int when ``integer``) within [min, max] (open ends with ``*_open``)."""
        value, given = self._raw(key, default)
        if not given:
            return value
        what = "an integer" if integer else "a number"
        if isinstance(value, str):
            value = _yaml12_number(value)
            if integer and isinstance(value, float) and value.is_integer():
                value = int(value)
        if isinstance(value, bool) or not isinstance(value, int | float) or (integer and not isinstance(value, int)):
            raise self.error(key, f"must be {what}, got {_kind(value)} {_shown(value)}")
        if not _finite(value):
            raise self.error(key, f"must be finite, got {_shown(value)}")
        if min is not None and (value < min or (min_open and value == min)):
            raise self.error(key, f"must be {'>' if min_open else '≥'} {min:g}, got {_shown(value)}")
        if max is not None and (value > max or (max_open and value == max)):
            raise self.error(key, f"must be {'<' if max_open else '≤'} {max:g}, got {_shown(value)}")
        return int(value) if integer else float(value)

    def boolean(self, key: str, default: Any = _MISSING) -> Any:
        value, given = self._raw(key, default)
        if given and not isinstance(value, bool):
            raise self.error(key, f"must be true or false, got {_kind(value)} {value!r}")
        return value

    def string(
        self,
        key: str,
        default: Any = _MISSING,
        *,
        choices: Sequence[str] | None = None,
        pattern: str | None = None,
        pattern_help: str = "",
    ) -> Any:
        value, given = self._raw(key, default)
        if not given:
            return value
        if not isinstance(value, str):
            raise self.error(key, f"must be a string, got {_kind(value)} {value!r}")
        if choices is not None and value not in choices:
            raise self.error(key, f"must be one of {', '.join(choices)}; got {value!r}")
        if pattern is not None and not re.fullmatch(pattern, value):
            raise self.error(key, f"{value!r} is not valid{': ' + pattern_help if pattern_help else ''}")
        return value

    def string_list(self, key: str, default: Any = _MISSING, *, check: Callable[[str], str | None] | None = None):
        """A list of strings (a single string is accepted as a one-element list); ``check`` returns an error."""
        value, given = self._raw(key, default)
        if not given:
            return tuple(value)
        items = [Node(value, self._items[key].line)] if isinstance(value, str) else value
        if not isinstance(items, list):
            raise self.error(key, f"must be a list of strings, got {_kind(value)}")
        out = []
        for i, item in enumerate(items):
            if not isinstance(item.value, str):
                raise self.error_at(item.line, f"{self.key_path(key)}[{i}]", f"must be a string, got {item.value!r}")
            problem = check(item.value) if check is not None else None
            if problem:
                raise self.error_at(item.line, f"{self.key_path(key)}[{i}]", problem)
            out.append(item.value)
        return tuple(out)

    def vector(self, key: str, default: Any = _MISSING, *, length: int = 3) -> Any:
        """A list of ``length`` finite numbers -> tuple of floats."""
        value, given = self._raw(key, default)
        if not given:
            return None if value is None else tuple(value)
        if not isinstance(value, list) or len(value) != length:
            raise self.error(key, f"must be a list of {length} numbers, got {_render(value)}")
        out = []
        for item in value:
            v = _yaml12_number(item.value)
            if isinstance(v, bool) or not isinstance(v, int | float) or not _finite(v):
                raise self.error(key, f"must be a list of {length} finite numbers, got {_render(value)}")
            out.append(float(v))
        return tuple(out)

    def path_value(self, key: str, default: Any = _MISSING, *, must_exist: bool = True) -> Path | None:
        """A file path (``default`` None makes it optional); relative paths resolve against the config's directory."""
        value = self.string(key, default)
        if value is None:
            return None
        if value == "":
            raise self.error(key, "must not be empty")
        try:
            path = Path(value).expanduser()
        except RuntimeError:  # "~user/..." naming no known user, or no home directory
            raise self.error(key, f"cannot expand {value.split('/')[0]!r}: no such user or home directory") from None
        if not path.is_absolute():
            path = self.file.resolve().parent / path
        if must_exist and not path.exists():
            raise self.error(key, f"file not found: {path}")
        return path

    def finish(self) -> None:
        """Reject keys that were not read (a removed key with the reason it went, see :data:`REMOVED_KEYS`)."""
        for key, node in self._items.items():
            if key not in self._used:
                removed = REMOVED_KEYS.get(self.key_path(key))
                if removed is not None:
                    raise self.error_at(node.line, self.key_path(key), f"unknown key ({removed})")
                known = sorted(self._used)
                close = difflib.get_close_matches(key, known, n=1)
                hint = f"; did you mean {close[0]}?" if close else (f" (known: {', '.join(known)})" if known else "")
                raise self.error_at(node.line, self.key_path(key), f"unknown key{hint}")


def _yaml12_number(value: Any) -> Any:
    """``value``, a string such as ``1e3`` as the float YAML 1.2 reads (PyYAML, YAML 1.1, leaves it a string)."""
    return float(value) if isinstance(value, str) and _YAML12_FLOAT.fullmatch(value.strip()) else value


def _finite(value: int | float) -> bool:
    """Whether ``value`` is a finite number a float can hold: not inf or nan, no integer beyond ±1.8e308."""
    return math.isfinite(value) if isinstance(value, float) else abs(value) <= sys.float_info.max


def _shown(value: Any) -> str:
    """``repr(value)``, an integer of more than 20 digits shortened to its first and last digits and its length."""
    text = repr(value)
    if isinstance(value, int) and len(text.lstrip("-")) > 20:
        digits = text.lstrip("-")
        return f"{text[: len(text) - len(digits)]}{digits[:3]}…{digits[-3:]} ({len(digits)} digits)"
    return text


def _kind(value: Any) -> str:
    if isinstance(value, dict):
        return "a mapping"
    if isinstance(value, list):
        return "a list"
    if value is None:
        return "null"
    return type(value).__name__


def _render(value: Any) -> str:
    if isinstance(value, list):
        return "[" + ", ".join(_render(item.value) for item in value) + "]"
    if isinstance(value, dict):
        return "a mapping"
    return _shown(value)
