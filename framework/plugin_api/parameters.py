"""Typed plugin parameters: a plugin class written as an attrs class declares its configuration.

Every field that ``__init__`` takes is a parameter (``registry``, which the registry passes itself, is
not), with its type annotation, its default, a one-line description (``parameter(..., doc=...)``) and
optionally a range check. :func:`build_from_table` is the one place a configuration table becomes a plugin
(or another typed table, such as ``[fit]``):
it rejects unknown keys and values of the wrong type naming the plugin, converts what is unambiguous (an
integer where a float is expected, a TOML array where a tuple is), and lets the class's validators check
ranges. :func:`describe_parameters` is what ``mmcsplat plugins --show NAME`` prints.

Hand-written rather than cattrs: the checks needed here are a few lines over ``typing`` introspection,
and the errors must name the plugin and the key in the words of a configuration file.
"""

from __future__ import annotations

import math
import types
import typing
from collections.abc import Callable, Iterable, Mapping
from typing import Any

import attrs

from .errors import InputError

#: The metadata key of a field's one-line description.
DOC = "mmcsplat.doc"
#: The factory parameter the registry fills with itself; never a configuration key.
REGISTRY_PARAMETER = "registry"


def parameter(default: Any = attrs.NOTHING, *, doc: str, factory: Callable[[], Any] | None = None,
              validator: Callable[[Any, Any, Any], None] | None = None, converter: Callable[[Any], Any] | None = None,
              kw_only: bool = False) -> Any:
    """A documented parameter field: ``default`` (or ``factory`` for a mutable default; neither: required),
    ``doc`` the line ``plugins --show`` prints, ``validator`` an attrs validator (e.g. :func:`at_least`);
    ``kw_only`` for a required parameter of a class whose base has parameters with defaults."""
    return attrs.field(default=default, factory=factory, validator=validator, converter=converter, metadata={DOC: doc}, kw_only=kw_only)


def non_empty(_instance: Any, field: attrs.Attribute, value: Any) -> None:
    """Validator: the value (a file's path, a name) is not the empty string, which would read as the current folder."""
    if value is not None and not str(value).strip():
        raise ValueError(f"{field.name} is empty: set {field.name}=… to a file")


def at_least(bound: float) -> Callable[[Any, Any, Any], None]:
    """Validator: the value (when not ``None``) is ≥ ``bound``."""
    return _bound(lambda value: value >= bound, f"≥ {bound}")


def finite_positive(_instance: Any, field: attrs.Attribute, value: Any) -> None:
    """Validator: the value (when not ``None``) is a finite number > 0 (a learning rate, a size)."""
    if value is not None and not 0 < value < math.inf:
        raise ValueError(f"{field.name} must be a finite number > 0, got {value!r}")


def above(bound: float) -> Callable[[Any, Any, Any], None]:
    """Validator: the value (when not ``None``) is > ``bound``."""
    return _bound(lambda value: value > bound, f"> {bound}")


def between(low: float, high: float) -> Callable[[Any, Any, Any], None]:
    """Validator: ``low`` ≤ value ≤ ``high`` (when not ``None``)."""
    return _bound(lambda value: low <= value <= high, f"between {low} and {high}")


def one_of(*choices: str) -> Callable[[Any, Any, Any], None]:
    """Validator: the value is one of ``choices``."""

    def check(_instance: Any, field: attrs.Attribute, value: Any) -> None:
        if value not in choices:
            raise ValueError(f"{field.name} must be one of {', '.join(map(repr, choices))}, got {value!r}")

    return check


def _bound(holds: Callable[[Any], bool], text: str) -> Callable[[Any, Any, Any], None]:
    def check(_instance: Any, field: attrs.Attribute, value: Any) -> None:
        if value is not None and not holds(value):  # NaN fails every comparison, so it is refused too
            raise ValueError(f"{field.name} must be {text}, got {value!r}")

    return check


@attrs.frozen
class ParameterInfo:
    """One parameter as ``plugins --show`` lists it."""

    name: str
    type: str
    default: str
    doc: str


def configurable_fields(cls: type) -> list[attrs.Attribute]:
    """The fields of an attrs plugin class that a configuration table may set."""
    attrs.resolve_types(cls)
    return [field for field in attrs.fields(cls) if field.init and field.name != REGISTRY_PARAMETER]


def build_from_table(cls: Callable[..., Any], table: Mapping[str, Any], owner: str, **injected: Any) -> Any:
    """``cls(**table, **injected)`` after checking the table's keys and value types against ``cls``'s
    fields when it is an attrs class (any other factory is called as it is; :func:`checked_table`). Errors
    name ``owner`` (e.g. "dynamics 'iterative'") and the key at fault."""
    if not (isinstance(cls, type) and attrs.has(cls)):
        return cls(**table, **injected)
    checked = checked_table(cls, table, owner, injected)
    try:
        return cls(**checked, **injected)
    except (ValueError, TypeError) as error:
        raise InputError(f"{owner}: {error}") from error


def checked_table(cls: type, table: Mapping[str, Any], owner: str, injected: Iterable[str] = ()) -> dict[str, Any]:
    """``table`` with its values checked against the attrs plugin class ``cls``'s fields, without building it:
    an unknown key, a required one missing (unless ``injected``) or a value of the wrong type is an error
    naming ``owner`` and the key, before anything runs."""
    fields = {field.name: field for field in configurable_fields(cls)}
    unknown = sorted(set(table) - set(fields))
    if unknown:
        raise InputError(f"{owner}: unknown parameter(s) {', '.join(unknown)}; known: {', '.join(fields) or 'none'}")
    missing = [field for name, field in fields.items() if field.default is attrs.NOTHING and name not in table and name not in injected]
    if missing:
        wanted = "; ".join(f"set {field.name}=… ({field.metadata.get(DOC) or _type_text(field.type)})" for field in missing)
        raise InputError(f"{owner}: {wanted}, a required parameter (--set {missing[0].name}=VALUE, or in its configuration table)")
    return {key: _checked(value, fields[key].type, owner, key) for key, value in table.items()}


def describe_parameters(cls: Callable[..., Any]) -> list[ParameterInfo] | None:
    """The parameters of an attrs plugin class; ``None`` for any other factory."""
    if not (isinstance(cls, type) and attrs.has(cls)):
        return None
    rows = []
    for field in configurable_fields(cls):
        if isinstance(field.default, attrs.Factory):  # type: ignore[arg-type]
            default = repr(field.default.factory())
        else:
            default = "(required)" if field.default is attrs.NOTHING else repr(field.default)
        rows.append(ParameterInfo(field.name, _type_text(field.type), default, field.metadata.get(DOC, "")))
    return rows


def _checked(value: Any, expected: Any, owner: str, key: str) -> Any:
    """``value`` as ``expected`` (converted where unambiguous; a table into a nested attrs class, checked
    the same way), or an error naming ``owner`` and ``key``."""
    if isinstance(expected, type) and attrs.has(expected) and isinstance(value, Mapping):
        return build_from_table(expected, value, f"{owner} {key}")
    converted = _convert(value, expected)
    if converted is _MISMATCH:
        raise InputError(f"{owner}: parameter {key!r} must be {_type_text(expected)}, got {value!r}")
    return converted


_MISMATCH = object()


def _convert(value: Any, expected: Any) -> Any:
    if expected is None or expected is Any:
        return value
    origin, args = typing.get_origin(expected), typing.get_args(expected)
    if origin in (typing.Union, types.UnionType):
        for option in args:
            converted = _convert(value, option)
            if converted is not _MISMATCH:
                return converted
        return _MISMATCH
    if expected is type(None):
        return None if value is None else _MISMATCH
    if origin is typing.Literal:
        return value if value in args else _MISMATCH
    if expected is bool:
        return value if isinstance(value, bool) else _MISMATCH
    if expected is int:
        return value if isinstance(value, int) and not isinstance(value, bool) else _MISMATCH
    if expected is float:
        return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else _MISMATCH
    if expected is str:
        return value if isinstance(value, str) else _MISMATCH
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            return _MISMATCH
        items = args[:1] * len(value) if len(args) == 2 and args[1] is Ellipsis else args
        if len(items) != len(value):
            return _MISMATCH
        converted = tuple(_convert(item, kind) for item, kind in zip(value, items, strict=True))
        return _MISMATCH if _MISMATCH in converted else converted
    if origin in (Mapping, dict) or expected in (Mapping, dict):
        return dict(value) if isinstance(value, Mapping) else _MISMATCH
    return value if isinstance(expected, type) and isinstance(value, expected) else _MISMATCH


def _type_text(expected: Any) -> str:
    """A type as a configuration file's reader thinks of it."""
    names = {bool: "true or false", int: "an integer", float: "a number", str: "a string", type(None): "none"}
    if expected in names:
        return names[expected]
    origin, args = typing.get_origin(expected), typing.get_args(expected)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_type_text(option) for option in args)
    if origin is typing.Literal:
        return "one of " + ", ".join(map(repr, args))
    if origin is tuple:
        return "a list of " + (f"{_type_text(args[0])}s" if args[1:] == (Ellipsis,) else f"{len(args)} values")
    if origin in (Mapping, dict) or expected in (Mapping, dict):
        return "a table"
    return getattr(expected, "__name__", str(expected))
