"""YAML files that hold one mapping (configs, ``vehicle.yaml``, ``sensor.yaml``): read, or fail in one line.

Files from other people's tools are read within stated bounds, checked before any value is
built (an 836-byte "billion laughs" file would otherwise expand to gigabytes):

- at most :data:`MAX_YAML_BYTES` bytes;
- at most :data:`MAX_YAML_NODES` values once aliases (``*name``) are expanded, and no alias
  that refers to itself;
- at most :data:`MAX_YAML_DEPTH` levels of nesting.

Numbers with an exponent but no dot or exponent sign (``1e5``, ``1.0e308``) are read as
numbers, as YAML 1.2 does (YAML 1.1, PyYAML's default, reads them as text).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import yaml

from uavturb.errors import InputError

MAX_YAML_BYTES = 1 << 20  # 1 MiB
MAX_YAML_NODES = 100_000
MAX_YAML_DEPTH = 64


class _Bounds(Exception):
    """A stated bound of this module was exceeded (the message says which)."""


class BoundedLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` with a nesting limit (checked while composing) and YAML 1.2 exponents."""

    def __init__(self, stream):
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent, index):
        self._depth += 1
        if self._depth > MAX_YAML_DEPTH:
            raise _Bounds(f"nested deeper than {MAX_YAML_DEPTH} levels (the limit)")
        try:
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


def _unique_keys(loader: BoundedLoader, node: yaml.MappingNode, deep: bool = False) -> dict:
    """A mapping whose keys are unique: YAML says they must be, and PyYAML would keep the last of two silently
    (``mass`` written twice: which one did the user mean?)."""
    seen = set()
    for key_node, _ in node.value:  # the keys written here; a merge (<<) may be overridden, as YAML allows
        if not isinstance(key_node, yaml.ScalarNode) or key_node.tag == "tag:yaml.org,2002:merge":
            continue
        key = loader.construct_object(key_node)
        if key in seen:
            raise _Bounds(f"gives key {key!r} twice (line {key_node.start_mark.line + 1}); YAML keys must be unique")
        seen.add(key)
    return yaml.SafeLoader.construct_mapping(loader, node, deep=deep)


BoundedLoader.add_constructor("tag:yaml.org,2002:map", lambda loader, node: _unique_keys(loader, node, deep=True))


BoundedLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float", re.compile(r"^[-+]?[0-9][0-9_]*(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"))


def _expanded_size(node: yaml.Node) -> int:
    """Values ``node`` stands for once every alias is expanded; :class:`_Bounds` past the limit or
    on an alias that contains itself. Linear in the document (each node counted once, memoised)."""
    sizes: dict[int, int] = {}
    open_: set[int] = set()

    def size(n: yaml.Node) -> int:
        key = id(n)
        if key in sizes:
            return sizes[key]
        if key in open_:
            raise _Bounds("holds an alias that refers to itself")
        open_.add(key)
        if isinstance(n, yaml.MappingNode):
            total = 1 + sum(size(k) + size(v) for k, v in n.value)
        elif isinstance(n, yaml.SequenceNode):
            total = 1 + sum(size(v) for v in n.value)
        else:
            total = 1
        open_.discard(key)
        if total > MAX_YAML_NODES:
            raise _Bounds(f"expands to more than {MAX_YAML_NODES} values through its aliases (the limit)")
        sizes[key] = total
        return total

    return size(node)


def safe_load_bounded(text: str, where: str | Path) -> Any:
    """``text`` parsed as YAML (safe tags only) within this module's bounds; anything else raises
    :class:`InputError` naming ``where`` in one line."""
    if len(text) > MAX_YAML_BYTES:
        raise InputError(where, f"is {len(text)} characters long; YAML files are read up to {MAX_YAML_BYTES} bytes")
    try:  # the reader checks the characters as it is built: a control character fails here
        loader = BoundedLoader(text)
    except yaml.YAMLError as e:
        raise InputError(where, f"not valid YAML "
                                f"({type(e).__name__}: {getattr(e, 'reason', '') or 'unreadable'})") from None
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        _expanded_size(node)
        return loader.construct_document(node)
    except _Bounds as e:
        raise InputError(where, f"refused: {e}") from None
    except yaml.YAMLError as e:
        raise InputError(where, f"not valid YAML ({type(e).__name__})") from None
    except RecursionError:
        raise InputError(where, f"nested too deeply (the limit is {MAX_YAML_DEPTH} levels)") from None
    except ValueError as e:  # e.g. an integer of more than 4300 digits
        raise InputError(where, f"holds a value that cannot be read ({str(e)[:120]})") from None
    finally:
        loader.dispose()


def parse_yaml_mapping(text: str, where: str | Path, *, expected: str = "a mapping") -> dict[str, Any]:
    """``text`` parsed as YAML (:func:`safe_load_bounded`); an empty document is ``{}``. Anything
    but a mapping raises :class:`InputError` naming ``where``: ``not valid YAML (ScannerError)``,
    ``expected <expected>``."""
    d = safe_load_bounded(text, where)
    if d is None:
        return {}
    if not isinstance(d, dict):
        raise InputError(where, f"expected {expected}")
    return d


def read_yaml_text(path: str | Path, *, not_found: str = "file not found") -> str:
    """The text of the YAML file ``path``, checked against :data:`MAX_YAML_BYTES` before reading.
    Bytes that are not UTF-8 read as U+FFFD."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, not_found)
    try:
        size = path.stat().st_size
        if size > MAX_YAML_BYTES:
            raise InputError(path, f"is {size} bytes; YAML files are read up to {MAX_YAML_BYTES} bytes")
        return path.read_text(encoding="utf-8", errors="replace")
    except OSError as e:
        raise InputError(path, f"cannot be read ({e.strerror or type(e).__name__})") from None


def read_yaml_mapping(path: str | Path, *, expected: str = "a mapping",
                      not_found: str = "file not found") -> dict[str, Any]:
    """The mapping in the YAML file ``path`` (see :func:`parse_yaml_mapping`); a missing file raises
    :class:`InputError` ``<path>: <not_found>``. Bytes that are not UTF-8 read as U+FFFD."""
    return parse_yaml_mapping(read_yaml_text(path, not_found=not_found), path, expected=expected)
