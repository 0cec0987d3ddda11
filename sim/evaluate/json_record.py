"""Typed JSON records: frozen dataclasses read from and written to JSON objects, every key
checked.

:class:`JsonRecord` is the base of a schema's records (:mod:`sim.evaluate.record`, the
results.json schema): :meth:`JsonRecord.from_json` builds a record from a JSON object, checking
each key against the field's annotation (records, plain dataclasses, lists, dicts, unions,
numbers) and refusing an unknown key, a missing required one or a value of another kind with a
:class:`SchemaError` that names where; the keys a record was read with are remembered
(``present``) and :meth:`JsonRecord.to_json` writes those again, in field order, so a file read
and written again is the same file.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import types
import typing
from dataclasses import dataclass, field


class SchemaError(ValueError):
    """A results.json or run.json this code cannot read: not JSON, another schema_version, or a
    key or value the record does not hold (the message names where)."""


@dataclass(frozen=True, kw_only=True)
class JsonRecord:
    """A JSON object whose keys are the record's fields (subclasses: frozen dataclasses)."""

    schema_note: typing.ClassVar[str] = "this schema"
    """Names the schema in messages (e.g. its file and version)."""

    present: frozenset[str] | None = field(default=None, repr=False)
    """the keys the record was read with (written again, in field order); None: every field"""

    @classmethod
    def from_json(cls, data, where: str = ""):
        """The record of a JSON object; SchemaError for an unknown key, a missing required one
        or a value of another kind."""
        where = where or cls.__name__
        if not isinstance(data, dict):
            raise SchemaError(f"{where}: expected an object ({cls.__name__}), got "
                              f"{kind(data)}")
        names = [f.name for f in _fields(cls)]
        unknown = [k for k in data if k not in names]
        if unknown:
            raise SchemaError(f"{where}: {unknown[0]!r} is not a key of {cls.__name__} "
                              f"({cls.schema_note}); its keys are "
                              f"{', '.join(names)}")
        missing = [f.name for f in _fields(cls) if f.name not in data
                   and f.default is dataclasses.MISSING]
        if missing:
            raise SchemaError(f"{where}: {cls.__name__} needs {', '.join(missing)}")
        hints = _hints(cls)
        values = {k: _load(v, hints[k], f"{where}.{k}") for k, v in data.items()}
        present = None if set(data) == set(names) else frozenset(data)
        return cls(**values, present=present)

    def to_json(self) -> dict:
        """The JSON object: the present keys in field order."""
        return {f.name: _dump(getattr(self, f.name)) for f in _fields(type(self))
                if self.present is None or f.name in self.present}


@functools.cache
def _fields(cls) -> tuple:
    return tuple(f for f in dataclasses.fields(cls) if f.name != "present")


@functools.cache
def _hints(cls) -> dict:
    return typing.get_type_hints(cls)


def kind(value) -> str:
    """What a JSON value is, for messages: ``null`` or its Python type's name."""
    return "null" if value is None else type(value).__name__


def _load(value, hint, where: str):
    """``value`` checked against the annotation ``hint`` (records built, containers walked)."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        *first, last = [a for a in args if a is not type(None)]
        for option in first:
            with contextlib.suppress(SchemaError):
                return _load(value, option, where)
        return _load(value, last, where)
    if isinstance(hint, type) and dataclasses.is_dataclass(hint):
        if issubclass(hint, JsonRecord):
            return hint.from_json(value, where)
        return _plain_dataclass(hint, value, where)
    base = origin or hint
    if not isinstance(value, base) or (isinstance(value, bool) and base is not bool):
        if not (base is float and isinstance(value, int) and not isinstance(value, bool)):
            raise SchemaError(f"{where}: expected {getattr(base, '__name__', base)}, got "
                              f"{kind(value)} {value!r:.60}")
    if base is list and args:
        return [_load(v, args[0], f"{where}[{i}]") for i, v in enumerate(value)]
    if base is dict and args:
        return {k: _load(v, args[1], f"{where}[{k!r}]") for k, v in value.items()}
    return value


def _plain_dataclass(cls, value, where: str):
    """A dataclass of another module (:class:`GateCheck`): every field, no other key."""
    if not isinstance(value, dict):
        raise SchemaError(f"{where}: expected an object ({cls.__name__}), got {kind(value)}")
    names = [f.name for f in dataclasses.fields(cls)]
    if sorted(value) != sorted(names):
        raise SchemaError(f"{where}: {cls.__name__} has the keys {', '.join(names)}, got "
                          f"{', '.join(value)}")
    hints = _hints(cls)
    return cls(**{k: _load(value[k], hints[k], f"{where}.{k}") for k in names})


def _dump(value):
    if isinstance(value, JsonRecord):
        return value.to_json()
    if dataclasses.is_dataclass(value):
        return {f.name: _dump(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, list):
        return [_dump(v) for v in value]
    if isinstance(value, dict):
        return {k: _dump(v) for k, v in value.items()}
    return value
