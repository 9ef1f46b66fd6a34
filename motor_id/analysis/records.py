"""JSON of the analysis' result records: one writer for every record's dataclass.

A record is a dataclass with named, typed fields; :meth:`JsonRecord.to_dict` writes its
fields in their order, each under its name, nested records and sequences converted, and
leaves out a field whose :func:`optional` rule says so (an entry the JSON writes only
when it has something to say). ``to_dict`` is used at the edge only: the JSON a command
writes, the dict a test or a caller of the old shape reads.
"""

from __future__ import annotations

from collections.abc import Callable
import dataclasses
import math
from typing import Any


def _is_none(value: object, _record: object) -> bool:
    return value is None


def _is_empty(value: object, _record: object) -> bool:
    return not value


def omit_if_failed(_value: object, record: object) -> bool:
    """A field a failed record does not write (its ``failed`` field says why)."""
    return bool(getattr(record, 'failed', ''))


def optional(default: Any = None, *, when: Callable[[Any, Any], bool] | str = 'none',
             json: Callable[[Any], object] | None = None) -> Any:
    """A field that :meth:`JsonRecord.to_dict` leaves out ``when`` its value is None
    (``'none'``), falsy (``'empty'``), or ``when(value, record)`` is true.
    ``json``: how its value is written (default: as :func:`jsonable`)."""
    rule = {'none': _is_none, 'empty': _is_empty}[when] if isinstance(when, str) else when
    meta: dict[str, object] = {'omit': rule}
    if json is not None:
        meta['json'] = json
    if isinstance(default, (dict, list)):
        return dataclasses.field(default_factory=type(default), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def written(json: Callable[[Any], object], default: Any = dataclasses.MISSING) -> Any:
    """A field written as ``json(value)`` (a number JSON cannot hold, an object that is
    not a record)."""
    return dataclasses.field(default=default, metadata={'json': json})


def internal(default: Any = dataclasses.MISSING, **kw: Any) -> Any:
    """A field that :meth:`JsonRecord.to_dict` never writes (arrays for plots, masks)."""
    return dataclasses.field(default=default, repr=False, compare=False,
                             metadata={'internal': True}, **kw)


def finite(value: float | None) -> float | None:
    """None for a non-finite number (JSON has no inf or nan)."""
    return float(value) if value is not None and math.isfinite(value) else None


def jsonable(value: object) -> object:
    """``value`` with every record (anything with ``to_dict``) written as its dict, tuples
    as lists, mappings and lists copied."""
    to_dict = getattr(value, 'to_dict', None)
    if to_dict is not None and not isinstance(value, type):
        return to_dict()
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, dict):
        return {k: jsonable(v) for k, v in value.items()}
    return value


class JsonRecord:
    """Mixin of a result dataclass: :meth:`to_dict` writes its fields in order."""

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: every field in order, bar the internal ones and the optional ones
        their rule leaves out."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):   # type: ignore[arg-type]
            if f.metadata.get('internal'):
                continue
            value = getattr(self, f.name)
            omit = f.metadata.get('omit')
            if omit is not None and omit(value, self):
                continue
            how = f.metadata.get('json')
            out[f.name] = how(value) if how is not None else jsonable(value)
        return out
