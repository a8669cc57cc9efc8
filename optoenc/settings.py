"""Typed, documented, validated settings: the one way optoenc declares a knob.

A plugin's ``Config`` is a dataclass deriving from :class:`Settings` whose
fields are made with :func:`setting`. Each field carries its help text, its
SI unit and its allowed range; :func:`describe` turns a ``Config`` class into
the rows that the CLI listings, the JSON output and the generated settings
reference print, so documentation and validation share one source.

Example:
    >>> from dataclasses import dataclass
    >>> @dataclass
    ... class Config(Settings):
    ...     d2: float = setting(4e-3, "mask-to-sensor distance", unit="m", gt=0)
    >>> Config(d2=-1.0)
    Traceback (most recent call last):
    ...
    optoenc.errors.ConfigError: d2 = -1.0: must be > 0 m
"""

from __future__ import annotations

import dataclasses
import functools
import math
import re
import typing
from collections.abc import Mapping
from typing import Any, Iterable

from .errors import ConfigError

__all__ = [
    "Settings", "setting", "validate", "coerce", "field_value", "describe", "to_dict", "first_line", "Documented",
    "parse_hw",
]  # fmt: skip


def setting(
    default: Any = dataclasses.MISSING,
    help: str = "",
    *,
    unit: str = "",
    gt: float | None = None,
    ge: float | None = None,
    lt: float | None = None,
    le: float | None = None,
    choices: Iterable[Any] | None = None,
    default_factory: Any = dataclasses.MISSING,
) -> Any:
    """A dataclass field with help text, SI unit and allowed range.

    Args:
        default: default value (use ``default_factory`` for lists).
        help: one-line description shown in listings and docs.
        unit: SI unit of the value (``"m"``, ``"dB"``, ``""`` for none).
        gt, ge, lt, le: bounds (strictly greater, greater or equal, ...).
            They apply to every element of a tuple or list value.
        choices: the allowed values, if the setting is an enumeration.
        default_factory: a callable making the default (mutable defaults).
    """
    meta = {
        "help": help,
        "unit": unit,
        "gt": gt,
        "ge": ge,
        "lt": lt,
        "le": le,
        "choices": tuple(choices) if choices is not None else None,
    }
    if default_factory is not dataclasses.MISSING:
        return dataclasses.field(default_factory=default_factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def _allowed_text(meta: dict) -> str:
    unit = f" {meta['unit']}" if meta.get("unit") else ""
    if meta.get("choices") is not None:
        return "one of " + ", ".join(repr(c) for c in meta["choices"])
    parts = []
    for key, op in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<=")):
        if meta.get(key) is not None:
            parts.append(f"{op} {meta[key]:g}{unit}")
    return "must be " + " and ".join(parts) if parts else ""


def _without_none(tp: Any) -> Any:
    """``tp`` with ``Optional`` removed: ``X`` for ``Optional[X]`` (or ``X | None``), ``None`` for a union of several
    types, ``tp`` itself otherwise."""
    if typing.get_origin(tp) is typing.Union or type(tp).__name__ == "UnionType":
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        return args[0] if len(args) == 1 else None
    return tp


def _scalar_type(tp: Any) -> tuple[Any, int | None, bool]:
    """``(element type, fixed length or None, is a sequence)`` of a field annotation (``Optional`` removed)."""
    tp = _without_none(tp)
    if tp is None:
        return None, None, False
    origin = typing.get_origin(tp)
    if origin in (tuple, list):
        args = typing.get_args(tp)
        if not args:
            return None, None, True
        if origin is tuple and (len(args) < 2 or args[1] is not Ellipsis):
            return (args[0] if len(set(args)) == 1 else None), len(args), True
        return args[0], None, True
    return tp, None, False


@functools.lru_cache(maxsize=None)
def _field_types(cls: type) -> dict[str, tuple[Any, int | None, bool]]:
    try:
        hints = typing.get_type_hints(cls)
    except Exception:  # a plugin annotation that cannot be resolved: no type checks
        return {}
    return {name: _scalar_type(tp) for name, tp in hints.items()}


@functools.lru_cache(maxsize=None)
def _is_tuple(cls: type, name: str) -> bool:
    """Whether field ``name`` is annotated as a tuple (``Optional`` removed), not a list."""
    return typing.get_origin(_without_none(typing.get_type_hints(cls).get(name))) is tuple


@functools.lru_cache(maxsize=None)
def _required(cls: type) -> frozenset[str]:
    """Fields whose annotation does not admit None (and whose default is not None)."""
    try:
        hints = typing.get_type_hints(cls)
    except Exception:
        return frozenset()
    out = set()
    for f in dataclasses.fields(cls):
        tp = hints.get(f.name)
        args = typing.get_args(tp)
        optional = tp is Any or type(None) in args or tp is type(None)
        if tp is not None and not optional and f.default is not None:
            out.add(f.name)
    return frozenset(out)


_TYPE_WORDS = {float: "a number", int: "an integer", bool: "true or false", str: "a string"}


def _check_type(name: str, value: Any, expected: Any) -> None:
    if expected is float:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
    elif expected is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif expected is bool:
        ok = isinstance(value, bool)
    elif expected is str:  # a number is a fine spelling of some string settings (fidelity.padding = 0.5)
        ok = isinstance(value, (str, int, float)) and not isinstance(value, bool)
    else:
        return
    if not ok:
        raise ConfigError(name, value, f"must be {_TYPE_WORDS[expected]}, not {type(value).__name__}")


def _check_scalar(name: str, value: Any, meta: dict, expected: Any = None) -> None:
    if meta.get("choices") is not None:
        if value not in meta["choices"]:
            raise ConfigError(name, value, _allowed_text(meta))
        return
    _check_type(name, value, expected)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return
    if isinstance(value, float) and not math.isfinite(value):
        # inf satisfies "> 0": non-finite numbers are never a physical setting
        allowed = _allowed_text(meta).replace("must be ", "", 1)
        what = "NaN" if math.isnan(value) else "infinite"
        raise ConfigError(name, value, f"must be a finite number{' ' + allowed if allowed else ''}, not {what}")
    bounds = [meta.get(k) for k in ("gt", "ge", "lt", "le")]
    gt, ge, lt, le = bounds
    ok = (gt is None or value > gt) and (ge is None or value >= ge)
    ok = ok and (lt is None or value < lt) and (le is None or value <= le)
    if not ok:
        raise ConfigError(name, value, _allowed_text(meta))


def validate(config: Any) -> None:
    """Check every field of a settings dataclass against its declared range.

    Raises:
        ConfigError: naming the field, the value and what is allowed.
    """
    types = _field_types(type(config))
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if value is None:
            if f.name in _required(type(config)):
                raise ConfigError(f.name, None, f"must be set (null is not allowed); {_allowed_text(f.metadata) or 'see its description'}")
            continue
        expected, length, sequence = types.get(f.name, (None, None, False))
        if isinstance(value, (tuple, list)):
            if expected in _TYPE_WORDS and not sequence:
                raise ConfigError(f.name, list(value), f"must be {_TYPE_WORDS[expected]}, not a list")
            if length is not None and len(value) != length:
                raise ConfigError(f.name, list(value), f"must have {length} values, not {len(value)}")
            for v in value:
                if v is not None:
                    _check_scalar(f.name, v, f.metadata, expected)
        elif sequence:
            raise ConfigError(f.name, value, f"must be a list of {length or 'some'} values")
        elif dataclasses.is_dataclass(value):
            try:
                validate(value)
            except ConfigError as err:
                raise err.with_prefix(f.name) from None
        else:
            _check_scalar(f.name, value, f.metadata, expected)


_SEPARATORS = re.compile(r"\s*[x,]\s*|\s+")


def _sequence_from_text(name: str, text: str, element: Any, length: int | None) -> list:
    """``"24x32"``, ``"24,32"``, ``"[24, 32]"`` or ``"24 32"`` -> ``[24, 32]`` (elements as ``element``)."""
    example = "x".join(["24", "32", "8"][: length or 2])
    what = f"{length} values" if length else "values"
    body = text.strip().removeprefix("[").removesuffix("]").strip().lower()
    convert = element if element in (int, float) else (lambda v: v)
    try:
        return [convert(v) for v in _SEPARATORS.split(body)] if body else []
    except ValueError:
        raise ConfigError(name, text, f"must be {what}, written {example} or [{example.replace('x', ',')}]") from None


def field_value(cls: type, name: str, value: Any) -> Any:
    """``value`` as field ``name`` of the settings class ``cls`` holds it.

    A list or tuple setting given as text (the command line's ``24x32``,
    ``24,32`` or ``[24,32]``) becomes the tuple or list of its elements; a
    tuple setting given as a list becomes a tuple (the type of its default),
    so a configuration built from its own :func:`to_dict` equals it. Every
    other value is returned as it is (:func:`validate` judges it).

    Raises:
        ConfigError: text that is not a list of the setting's element type.
    """
    element, length, sequence = _field_types(cls).get(name, (None, None, False))
    if not sequence:
        return value
    if isinstance(value, str):
        value = _sequence_from_text(name, value, element, length)
    if isinstance(value, list) and _is_tuple(cls, name):
        return tuple(value)
    return value


def coerce(cls: type, value: Any, section: str) -> Any:
    """A ``cls`` settings object from ``value``: None (the defaults), a ``cls`` itself, or a mapping of its fields.

    This is how encoders, decoders, datasets and augmentations accept their
    settings (``Lens({"d2": 5e-3})``, ``sensor={"embedding": [6, 8]}``).

    Args:
        cls: a settings dataclass (a :class:`Settings` subclass).
        value: None, a ``cls`` instance or a mapping of field names to values.
        section: the settings section, named in errors (``"sensor"``).

    Raises:
        ConfigError: an unknown key (with the known ones), a value that is not
            allowed (its key prefixed with ``section``), or a ``value`` of
            another type.
    """
    if value is None:
        return cls()
    if isinstance(value, cls):
        return value
    if isinstance(value, Mapping):
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(value) - names)
        if unknown:
            raise ConfigError(f"{section}.{unknown[0]}", value[unknown[0]], f"unknown setting; known: {', '.join(sorted(names))}")
        try:
            return cls(**value)
        except ConfigError as err:
            raise err.with_prefix(section) from None
    raise ConfigError(section, value, f"must be a {cls.__name__} or a mapping")


@dataclasses.dataclass
class Settings:
    """Base of every settings dataclass: coerced (:func:`field_value`) and validated on construction."""

    def __post_init__(self) -> None:
        for name, (_, _, sequence) in _field_types(type(self)).items():
            if sequence:
                value = getattr(self, name, None)
                new = field_value(type(self), name, value)
                if new is not value:
                    setattr(self, name, new)
        validate(self)

    def replace(self, **changes: Any) -> "Settings":
        """A validated copy with some fields changed."""
        return dataclasses.replace(self, **changes)


def _type_name(tp: Any) -> str:
    if isinstance(tp, str):
        return tp
    origin = typing.get_origin(tp)
    if origin is None:
        return getattr(tp, "__name__", str(tp))
    args = ", ".join(_type_name(a) for a in typing.get_args(tp))
    name = getattr(origin, "__name__", str(origin))
    if name in ("Union", "UnionType"):
        return " | ".join(_type_name(a) for a in typing.get_args(tp))
    return f"{name}[{args}]"


def describe(config_cls: type) -> list[dict[str, Any]]:
    """Rows describing each setting of a settings dataclass.

    Returns:
        One dict per field: ``name``, ``type``, ``default``, ``unit``,
        ``help`` and ``allowed`` (the range or choices, in words).
    """
    hints = typing.get_type_hints(config_cls)
    rows = []
    for f in dataclasses.fields(config_cls):
        if f.default is not dataclasses.MISSING:
            default = f.default
        elif f.default_factory is not dataclasses.MISSING:  # type: ignore[misc]
            default = f.default_factory()  # type: ignore[misc]
        else:
            default = None
        if dataclasses.is_dataclass(default):
            default = to_dict(default)
        rows.append(
            {
                "name": f.name,
                "type": _type_name(hints.get(f.name, f.type)),
                "default": list(default) if isinstance(default, tuple) else default,
                "unit": f.metadata.get("unit", ""),
                "help": f.metadata.get("help", ""),
                "allowed": _allowed_text(dict(f.metadata)),
            }
        )
    return rows


def to_dict(config: Any) -> dict[str, Any]:
    """Plain, YAML/JSON-friendly dict of a settings dataclass (tuples as lists)."""

    def plain(v: Any) -> Any:
        if dataclasses.is_dataclass(v):
            return {f.name: plain(getattr(v, f.name)) for f in dataclasses.fields(v)}
        if isinstance(v, (tuple, list)):
            return [plain(x) for x in v]
        return v

    return plain(config)


def first_line(obj: Any) -> str:
    """The summary line of an object's docstring ("" if it has none)."""
    doc = (getattr(obj, "__doc__", None) or "").strip()
    return doc.splitlines()[0] if doc else ""


class Documented:
    """Mixin for plugin base classes: ``summary()`` is the class docstring's first line (listings, docs)."""

    @classmethod
    def summary(cls) -> str:
        return first_line(cls)


def parse_hw(key: str, text: str, example: str = "28x28") -> tuple[int, int]:
    """A command-line size ``"HxW"`` -> ``(H, W)`` positive integers, or a ConfigError naming ``key``."""
    try:
        h, w = (int(v) for v in str(text).lower().split("x"))
        if h >= 1 and w >= 1:
            return h, w
    except ValueError:
        pass
    raise ConfigError(key, text, f"must be HxW with positive integers, e.g. {example}")
