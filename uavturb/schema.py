"""Schemas of what a user sets: one way to declare, check and override settings.

Every settings object of the package is a dataclass whose fields declare, next to their default,
the values they accept (:func:`allowed`, an :class:`Allowed` in the field's metadata) and, where
a command line offers them as options, their help text and metavar. This module checks them the
same way everywhere:

- :func:`check_values`: every field's value against its :class:`Allowed`; the error names the key,
  the value and what is allowed (``trainer.max_epochs: 0 is not allowed; allowed: an integer >= 1``);
- :func:`check_keys`: keys that are not fields fail naming the key, the closest known one and the
  allowed ones (``preset quick: widht: unknown key (did you mean 'width'?); allowed: ...``);
- :func:`parse_overrides`: the one override syntax of the command line, ``key=value`` (dotted keys
  reach into nested settings and mappings: ``model.use_gru=false``, ``effects.ground_effect.mu=2``),
  each value read as a YAML scalar and typed by the field it sets, so ``width=abc`` fails naming
  ``width``; :func:`apply_overrides` sets them on a dataclass.

Users: the training config (:mod:`uavturb.runs.config`, composed with OmegaConf and checked
here), the simulator's dataset presets (:class:`uavturb.sim.dataset.presets.SimPreset`), the
troubles of ``generate flight`` (:class:`uavturb.sim.flights.condition_schema.Conditions`) and the
simulator's physics configs (:mod:`uavturb.io.physics_config`, whose schema of effects is the
registry :data:`uavturb.physics.effects.EFFECTS`). Relations between fields (split sizes that must
sum, a rate below another) stay with the settings class, in a short method of its own.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
import types
import typing
from typing import Any, Callable, Iterable, Mapping, Sequence

import yaml

from uavturb.errors import InputError


@dataclasses.dataclass(frozen=True)
class Allowed:
    """The values a field accepts, declared once next to the field (:func:`allowed`) and checked by
    :func:`check_values`.

    A number must lie within the given bounds (``ge``, ``gt``, ``le``, ``lt``; floats also finite)
    or be one of ``also`` (sentinels such as ``-1`` = off); a string must be one of ``choices``,
    match ``pattern`` (a full-match regular expression) or, with ``nonempty``, not be empty. A
    sequence (tuple or list) must have ``length`` items when given, at least one with ``nonempty``,
    and each item obeys the number rules. ``None`` passes where the field's type allows it.
    """

    ge: float | None = None
    gt: float | None = None
    le: float | None = None
    lt: float | None = None
    also: tuple[Any, ...] = ()
    choices: tuple[str, ...] | None = None
    pattern: str | None = None
    nonempty: bool = False
    length: int | None = None
    unit: str | None = None             # of the bounds, in the description (``Hz``)
    text: str | None = None             # how the allowed values are described (else generated)

    def accepts(self, value: Any) -> bool:
        if value is None or (not isinstance(value, (list, tuple, dict)) and value in self.also):
            return True
        if isinstance(value, (list, tuple)):
            if (self.length is not None and len(value) != self.length) or (self.nonempty and not value):
                return False
            return all(isinstance(v, (int, float)) and not isinstance(v, bool) and self._number(v) for v in value)
        if self.choices is not None and value not in self.choices:
            return False
        if self.pattern is not None and not re.fullmatch(self.pattern, str(value)):
            return False
        if self.nonempty and not str(value).strip():
            return False
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return self._number(value)
        return True

    def _number(self, value: float) -> bool:
        if isinstance(value, float) and not math.isfinite(value):
            return False
        return ((self.ge is None or value >= self.ge) and (self.gt is None or value > self.gt)
                and (self.le is None or value <= self.le) and (self.lt is None or value < self.lt))

    def describe(self, noun: str = "a number") -> str:
        """What is allowed, in words (``an integer >= 1``, ``one of body, euroc``)."""
        if self.text:
            return self.text
        if self.choices is not None:
            return "one of " + ", ".join(self.choices)
        if self.nonempty and self.ge is None and self.gt is None:
            return "a non-empty string"
        bounds = [f"{op} {b:g}" for op, b in ((">=", self.ge), (">", self.gt), ("<=", self.le), ("<", self.lt))
                  if b is not None]
        out = f"{noun} " + " and ".join(bounds) if bounds else noun
        out += f" {self.unit}" if self.unit and bounds else ""
        return out + "".join(f" or {a}" for a in self.also)


def allowed(default: Any = dataclasses.MISSING, *, default_factory: Any = dataclasses.MISSING,
            help: str | None = None, metavar: str | None = None, **kw: Any) -> Any:
    """A dataclass field with default ``default`` (or ``default_factory``) whose values are limited by
    :class:`Allowed` (``kw``); ``help`` and ``metavar`` describe it where a command line offers it."""
    metadata: dict[str, Any] = {"allowed": Allowed(**kw)}
    if help is not None:
        metadata["help"] = help
    if metavar is not None:
        metadata["metavar"] = metavar
    return dataclasses.field(default=default, default_factory=default_factory, metadata=metadata)


def option_name(key: str) -> str:
    """The command-line option of a field: ``rate_hz`` -> ``--rate-hz``."""
    return "--" + key.replace("_", "-")


# --- checks ---------------------------------------------------------------------------------------


def did_you_mean(value: Any, known: Iterable[str]) -> str:
    """`` (did you mean 'width'?)`` for a string close to one of ``known``; else ``""``."""
    if not isinstance(value, str):
        return ""
    close = difflib.get_close_matches(value, list(known), n=1, cutoff=0.6) or \
        difflib.get_close_matches(value.lower(), list(known), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def check_keys(keys: Iterable[str], known: Sequence[str], where: Callable[[str], str] = str,
               noun: str = "key") -> None:
    """Raise :class:`InputError` for the first of ``keys`` not in ``known``: ``where(key)`` names it,
    the problem gives the closest known key and every allowed one."""
    for key in keys:
        if key not in known:
            raise InputError(where(key), f"unknown {noun}{did_you_mean(key, known)}; allowed: {', '.join(known)}")


def field_types(cls: Any) -> dict[str, Any]:
    """``{field name: resolved type}`` of a dataclass (string annotations resolved)."""
    return typing.get_type_hints(cls)


def _base_type(typ: Any) -> Any:
    """``int | None`` -> ``int``; other types unchanged."""
    if typing.get_origin(typ) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(typ) if a is not type(None)]
        return args[0] if len(args) == 1 else typ
    return typ


def _noun(typ: Any) -> str:
    base = _base_type(typ)
    item = typing.get_args(base)[0] if typing.get_origin(base) in (tuple, list) and typing.get_args(base) else None
    if base is int or item is int:
        return "an integer" if base is int else "integers"
    return "numbers" if typing.get_origin(base) in (tuple, list) or base in (tuple, list) else "a number"


def check_values(obj: Any, cls: Any = None, prefix: str = "", name: Callable[[str], str] | None = None) -> None:
    """Check every value of ``obj`` (a dataclass instance, or a mapping such as an OmegaConf
    DictConfig of the dataclass ``cls``) against the :class:`Allowed` declared on its field,
    nested dataclasses included.

    Parameters
    ----------
    name : how a key is named in the error (default ``prefix + key``; e.g. :func:`option_name`).

    Raises
    ------
    InputError : naming the first key whose value is not allowed, the value and what is.
    """
    cls = type(obj) if cls is None else cls
    hints = field_types(cls)
    for f in dataclasses.fields(cls):
        value = obj.get(f.name) if isinstance(obj, Mapping) else getattr(obj, f.name)
        key = name(f.name) if name is not None else f"{prefix}{f.name}"
        if dataclasses.is_dataclass(hints[f.name]):
            check_values(value, hints[f.name], key + ".", name)
            continue
        rule = f.metadata.get("allowed")
        if rule is not None and not (rule.accepts(value) and _of_type(value, hints[f.name])):
            hint = did_you_mean(value, rule.choices) if rule.choices is not None else ""
            raise InputError(key, f"{value!r} is not allowed; allowed: {rule.describe(_noun(hints[f.name]))}{hint}")


def _of_type(value: Any, typ: Any) -> bool:
    """Whether ``value`` may be a value of a field typed ``typ`` (scalars only; an integer is a number)."""
    optional = typing.get_origin(typ) in (typing.Union, types.UnionType) and type(None) in typing.get_args(typ)
    if value is None:
        return optional
    base = _base_type(typ)
    if base is bool:
        return isinstance(value, bool)
    if base is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if base is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if base is str:
        return isinstance(value, str)
    return True


# --- the one override syntax ----------------------------------------------------------------------


def split_override(item: str, where: str = "override") -> tuple[str, str]:
    """``"model.use_gru=false"`` -> ``("model.use_gru", "false")``.

    Raises
    ------
    InputError : no ``=`` or no key (naming ``where`` and the item).
    """
    key, sep, value = str(item).partition("=")
    if not sep or not key.strip() or key.strip().startswith("-"):
        raise InputError(where, f"expected KEY=VALUE, got {item!r}")
    return key.strip(), value


def read_scalar(text: str, key: str) -> Any:
    """``text`` read as a YAML value (``64``, ``0.5``, ``true``, ``null``, ``[1, 2]``, ``{mu: 2}``)."""
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError:
        raise InputError(key, f"cannot read value {text!r}") from None


def read_value(text: str, typ: Any, key: str) -> Any:
    """The value of ``key=text`` for a field of type ``typ``.

    YAML decides what the text is; the field's type what it may be: a string field takes the text
    as written (``None`` for ``null`` where allowed), a float field also ``1e-3`` and ``nan`` (left
    to the range check), a tuple field a YAML list or ``a,b``; an integer given for a float field
    stays as written (a dataset's config hash is that of what the user wrote, as before).

    Raises
    ------
    InputError : naming ``key`` and the type expected, e.g. ``width: expected an integer, got 'abc'``.
    """
    value = read_scalar(text, key)
    optional = typing.get_origin(typ) in (typing.Union, types.UnionType) and type(None) in typing.get_args(typ)
    if value is None and optional:
        return None
    base = _base_type(typ)
    origin = typing.get_origin(base) or base

    def wrong(expected: str) -> InputError:
        return InputError(key, f"expected {expected}, got {text!r}")

    if dataclasses.is_dataclass(base):
        if not isinstance(value, dict):
            raise InputError(key, f"a group of keys; set one of them ({key}.KEY=VALUE) or a mapping")
        return value
    if base is bool:
        if not isinstance(value, bool):
            raise wrong("true or false")
        return value
    if base is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise wrong("an integer")
        return value
    if base is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return value
        try:
            return float(str(value))
        except ValueError:
            raise wrong("a number") from None
    if base is str:
        return value if isinstance(value, str) else text.strip()
    if origin in (tuple, list):
        items = value if isinstance(value, list) else \
            [read_scalar(t, key) for t in text.split(",")] if isinstance(value, str) else [value]
        item_types = [a for a in typing.get_args(base) if a is not Ellipsis]
        if item_types:
            try:
                items = [read_value(str(v), item_types[min(i, len(item_types) - 1)], key) for i, v in enumerate(items)]
            except InputError:
                raise wrong(f"{_noun(base)} separated by commas (or a YAML list)") from None
        return tuple(items) if origin is tuple else list(items)
    if origin is dict:
        if not isinstance(value, dict):
            raise wrong("a mapping ({key: value, ...})")
        return value
    return value


def parse_overrides(items: Iterable[str], schema: Any, where: Callable[[str], str] = str,
                    option: str = "override") -> dict[str, Any]:
    """``key=value`` strings as ``{dotted key: value}``, each value typed by its field of the
    dataclass ``schema``.

    A dotted key descends into nested dataclasses (``model.use_gru=false``) and into mapping fields
    (``effects.ground_effect.mu=2``: the path after the field's name is inside its mapping, whose
    values are read as YAML); later items win.

    Parameters
    ----------
    where : how a key is named in errors (e.g. ``lambda k: f"preset quick: {k}"``).
    option : what the items were given as, for a malformed item (``--set``).

    Raises
    ------
    InputError : malformed item, unknown key (with the closest and the allowed keys), a value its
        field cannot take.
    """
    out: dict[str, Any] = {}
    for item in items:
        key, text = split_override(item, option)
        out[key] = _typed(schema, key, text, where)
    return out


def _typed(schema: Any, key: str, text: str, where: Callable[[str], str]) -> Any:
    """The value of ``key=text`` in the dataclass ``schema`` (see :func:`parse_overrides`)."""
    cls, parts = schema, key.split(".")
    for i, part in enumerate(parts):
        path = ".".join(parts[:i + 1])
        hints = field_types(cls)
        check_keys([part], list(hints), lambda k: where(path))
        typ = _base_type(hints[part])
        if i == len(parts) - 1:
            return read_value(text, hints[part], where(key))
        if (typing.get_origin(typ) or typ) is dict:
            return read_scalar(text, where(key))
        if not dataclasses.is_dataclass(typ):
            raise InputError(where(path), f"has no keys under it (set it as {path}=VALUE)")
        cls = typ
    raise AssertionError("unreachable")  # the loop returns at the last part


def nested(flat: Mapping[str, Any]) -> dict[str, Any]:
    """``{"model.use_gru": False}`` -> ``{"model": {"use_gru": False}}`` (later keys win)."""
    out: dict[str, Any] = {}
    for key, value in flat.items():
        *parents, last = key.split(".")
        node = out
        for p in parents:
            if not isinstance(node.get(p), dict):
                node[p] = {}
            node = node[p]
        node[last] = value
    return out


def _set_in(mapping: Mapping[str, Any], layer: Mapping[str, Any]) -> dict[str, Any]:
    """A copy of ``mapping`` with the nested ``layer``'s leaves set (copies all the way down)."""
    out = dict(mapping or {})
    for k, v in layer.items():
        out[k] = _set_in(out[k] if isinstance(out.get(k), dict) else {}, v) if isinstance(v, dict) else v
    return out


def apply_overrides(obj: Any, overrides: Mapping[str, Any], where: Callable[[str], str] = str) -> Any:
    """A copy of the dataclass ``obj`` with the overrides of :func:`parse_overrides` (or keyword
    arguments: ``width=64``): a plain key replaces the field's value, a dotted one sets a value
    inside the field's dataclass or mapping and keeps the rest.

    Raises
    ------
    InputError : a key that is no field of ``obj`` (see :func:`check_keys`).
    """
    check_keys([k.split(".")[0] for k in overrides], [f.name for f in dataclasses.fields(obj)], where)
    changes: dict[str, Any] = {k: v for k, v in overrides.items() if "." not in k}
    for key, inner in nested({k: v for k, v in overrides.items() if "." in k}).items():
        current = changes.get(key, getattr(obj, key))
        if dataclasses.is_dataclass(current):
            changes[key] = apply_overrides(current, {".".join(p): v for p, v in _leaves(inner, ())},
                                           lambda k, key=key: where(f"{key}.{k}"))
        else:
            changes[key] = _set_in(current if isinstance(current, dict) else {}, inner)
    return dataclasses.replace(obj, **changes)


def _leaves(d: Mapping[str, Any], path: tuple[str, ...]) -> Iterable[tuple[tuple[str, ...], Any]]:
    for k, v in d.items():
        if isinstance(v, dict) and v:
            yield from _leaves(v, (*path, k))
        else:
            yield (*path, k), v


__all__ = ["Allowed", "allowed", "apply_overrides", "check_keys", "check_values", "did_you_mean", "field_types",
           "nested", "option_name", "parse_overrides", "read_scalar", "read_value", "split_override"]
