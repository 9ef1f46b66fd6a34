"""Typed result records: frozen dataclasses with one ``to_dict()`` / ``from_dict()`` edge.

A result block is a frozen dataclass whose fields are named and typed; the JSON shape is
its fields in their order. A field declared with :func:`optional` is left out of the
JSON while it is None (a key that exists only in some reports); any other None is
written as null. Nested records, lists, tuples and dicts of them serialise recursively
(tuples as lists), so a report's JSON keeps the same keys in the same order as its
records' fields.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from typing import Any, TypeVar, Union

_OMIT = 'omit_if_none'
R = TypeVar('R', bound='Record')


def optional(default: Any = None) -> Any:
    """A field left out of the JSON while it is None (default None)."""
    return dataclasses.field(default=default, metadata={_OMIT: True})


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
        """JSON-ready: the fields in order, :func:`optional` ones left out while None."""
        out = {}
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            v = getattr(self, f.name)
            if v is None and f.metadata.get(_OMIT):
                continue
            out[f.name] = _out(v)
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
