"""Typed result records: frozen dataclasses with one ``to_dict()`` / ``from_dict()`` edge.

A result block is a frozen dataclass whose fields are named and typed; the JSON shape is
its fields in their order. A field declared with :func:`optional` is left out of the
JSON while it is None (a key that exists only in some reports; other rules: while
empty, while the record failed); any other None is written as null. :func:`written`
fields are written through a converter, :func:`internal` ones not at all. Nested
records, lists, tuples and dicts of them serialise recursively (tuples as lists), so a
report's JSON keeps the same keys in the same order as its records' fields.
"""

from __future__ import annotations

from collections.abc import Callable
import dataclasses
import math
import types
import typing
from typing import Any, TypeVar, Union

_OMIT = 'omit_if_none'
_JSON = 'json'
_INTERNAL = 'internal'
_RULES: dict[str, Callable[[Any, Any], bool]] = {
    'none': lambda value, _record: value is None,
    'empty': lambda value, _record: not value,
}
R = TypeVar('R', bound='Record')


def optional(default: Any = None, *, when: Callable[[Any, Any], bool] | str = 'none',
             json: Callable[[Any], object] | None = None) -> Any:
    """A field left out of the JSON while it is None (default None); ``when='empty'``:
    while it is falsy; ``when(value, record)``: while that is true (:func:`omit_if_failed`).
    ``json``: how its value is written (default as any other field)."""
    meta: dict[str, object] = {_OMIT: _RULES[when] if isinstance(when, str) else when}
    if json is not None:
        meta[_JSON] = json
    if isinstance(default, (dict, list)):
        return dataclasses.field(default_factory=type(default), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def written(json: Callable[[Any], object], default: Any = dataclasses.MISSING) -> Any:
    """A field always written, as ``json(value)`` (a number JSON cannot hold, an object
    that is not a record)."""
    return dataclasses.field(default=default, metadata={_JSON: json})


def internal(default: Any = dataclasses.MISSING, **kw: Any) -> Any:
    """A field the JSON never holds (per-sample arrays, masks)."""
    return dataclasses.field(default=default, repr=False, compare=False,
                             metadata={_INTERNAL: True}, **kw)


def omit_if_failed(_value: object, record: object) -> bool:
    """Rule of :func:`optional`: left out of a record whose ``failed`` says why it has
    nothing."""
    return bool(getattr(record, 'failed', ''))


def finite(value: float | None) -> float | None:
    """None for a non-finite number (JSON has no inf or nan)."""
    return float(value) if value is not None and math.isfinite(value) else None


def _out(value: Any) -> Any:
    if isinstance(value, Record):
        return value.to_dict()
    if isinstance(value, (list, tuple)):
        return [_out(v) for v in value]
    if isinstance(value, dict):
        return {k: _out(v) for k, v in value.items()}
    return value


class Record:
    """Base of the frozen result dataclasses: JSON out and back in at the edges."""

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: the fields in order, :func:`optional` ones left out by their rule
        (while None), :func:`internal` ones never written."""
        out = {}
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            if f.metadata.get(_INTERNAL):
                continue
            v = getattr(self, f.name)
            omit = f.metadata.get(_OMIT)
            if omit is not None and omit(v, self):
                continue
            how = f.metadata.get(_JSON)
            out[f.name] = how(v) if how is not None else _out(v)
        return out

    @classmethod
    def from_dict(cls: type[R], d: typing.Mapping[str, Any]) -> R:
        """The record of a ``to_dict()`` (unknown keys ignored, nested records rebuilt)."""
        hints = typing.get_type_hints(cls)
        kw = {f.name: _in(hints[f.name], d[f.name])
              for f in dataclasses.fields(cls) if f.name in d}  # type: ignore[arg-type]
        return cls(**kw)


def _in(tp: Any, value: Any) -> Any:
    """``value`` read back as type ``tp`` (records, their lists and dicts, optionals)."""
    if value is None:
        return None
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (Union, types.UnionType):
        inner = [a for a in args if a is not type(None)]
        if len(inner) == 1:
            return _in(inner[0], value)
        records = [a for a in inner if isinstance(a, type) and issubclass(a, Record)]
        return records[0].from_dict(value) if records and isinstance(value, dict) else value
    if isinstance(tp, type) and issubclass(tp, Record):
        return tp.from_dict(value)
    if origin is list:
        return [_in(args[0], v) for v in value]
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_in(args[0], v) for v in value)
        return tuple(_in(a, v) for a, v in zip(args, value, strict=True))
    if origin is dict:
        return {k: _in(args[1], v) for k, v in value.items()}
    return value
