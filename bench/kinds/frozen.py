"""Frozen records without generated code: the base of the kind records (:mod:`bench.kinds.record`).

A class deriving from :class:`Frozen` declares its fields as a dataclass does (annotations, with
defaults after the fields without); instances take them positionally or by keyword, cannot be
changed afterwards, compare and hash by their fields' values, show them in ``repr`` and are
copied with :meth:`Frozen.replace`. Type checkers read such a class as a frozen dataclass
(``typing.dataclass_transform``).

Why not ``@dataclass(frozen=True)``: it writes each class's ``__init__``, ``__eq__``, ``__repr__``,
``__hash__``, ``__setattr__``... as source text and compiles it when the module is imported, which no
bytecode cache keeps: for the twelve kind records that was ≈ 10 ms of every ``bench`` command that
reads a kind (``bench validate`` included; docs/benchmarks.md, "Instrument kinds"). Here every
class shares the methods below, and making a class only reads its annotations.

No field may be named ``replace``; defaults are shared between instances, so they must be
immutable (tuples, not lists) — as a frozen dataclass's must be in practice. A module declaring such
a class writes ``from __future__ import annotations`` (the fields are read from the class's
annotations as written, which Python 3.14 otherwise defers).
"""

from __future__ import annotations

from typing import Any, TypeVar, dataclass_transform

_R = TypeVar("_R", bound="Frozen")
_MISSING = object()


class _FrozenMeta(type):
    """Turns the annotated class attributes into ``__slots__`` and remembers their order and defaults."""

    def __new__(mcs, name: str, bases: tuple[type, ...], ns: dict[str, Any], **kw: Any) -> type:
        if "__annotations__" not in ns and "__annotate__" in ns:  # Python >= 3.14's deferred annotations
            raise TypeError(f"{name}: a Frozen record's module needs 'from __future__ import annotations' (its fields are read from them)")
        own = [n for n in ns.get("__annotations__", {}) if not n.startswith("_")]
        inherited: tuple[str, ...] = ()
        defaults: dict[str, Any] = {}
        for base in bases:
            inherited += tuple(n for n in getattr(base, "_fields", ()) if n not in inherited)
            defaults.update(getattr(base, "_defaults", {}))
        for n in own:
            value = ns.pop(n, _MISSING)
            if value is not _MISSING:
                defaults[n] = value
            elif n in defaults:
                del defaults[n]
        fields = inherited + tuple(n for n in own if n not in inherited)
        required = [n for n in fields if n not in defaults]
        late = [n for n in required if fields.index(n) > min((fields.index(d) for d in defaults), default=len(fields))]
        if late:
            raise TypeError(f"{name}: field {late[0]!r} without a default follows one with a default")
        ns["__slots__"] = tuple(n for n in own if n not in inherited)
        ns["_fields"] = fields
        ns["__match_args__"] = fields  # ``case Signal(name, units):`` as with a dataclass
        ns["_defaults"] = defaults
        return super().__new__(mcs, name, bases, ns, **kw)


@dataclass_transform(eq_default=True)
class Frozen(metaclass=_FrozenMeta):
    """A frozen record (see the module docstring)."""

    __slots__ = ()
    _fields: tuple[str, ...] = ()
    _defaults: dict[str, Any] = {}

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        cls = type(self)
        fields = cls._fields
        if len(args) > len(fields):
            raise TypeError(f"{cls.__name__}() takes {len(fields)} positional arguments but {len(args)} were given")
        values = dict(cls._defaults)
        values.update(zip(fields, args))
        for key, value in kwargs.items():
            if key not in fields:
                raise TypeError(f"{cls.__name__}() got an unexpected keyword argument {key!r}")
            if fields.index(key) < len(args):
                raise TypeError(f"{cls.__name__}() got multiple values for argument {key!r}")
            values[key] = value
        missing = [n for n in fields if n not in values]
        if missing:
            raise TypeError(f"{cls.__name__}() missing required argument(s): {', '.join(map(repr, missing))}")
        for n in fields:
            object.__setattr__(self, n, values[n])

    def _values(self) -> tuple[Any, ...]:
        return tuple(getattr(self, n) for n in self._fields)

    def replace(self: _R, **changes: Any) -> _R:
        """A copy with ``changes`` (field -> new value), as ``dataclasses.replace`` makes one."""
        return type(self)(**{**dict(zip(self._fields, self._values())), **changes})

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError(f"cannot assign to field {name!r}: a {type(self).__name__} is frozen")

    def __delattr__(self, name: str) -> None:
        raise AttributeError(f"cannot delete field {name!r}: a {type(self).__name__} is frozen")

    def __eq__(self, other: object) -> bool:
        if other.__class__ is not self.__class__:
            return NotImplemented
        return self._values() == other._values()  # type: ignore[attr-defined]

    def __hash__(self) -> int:
        return hash(self._values())

    def __repr__(self) -> str:
        return f"{type(self).__qualname__}({', '.join(f'{n}={getattr(self, n)!r}' for n in self._fields)})"

    def __getstate__(self) -> tuple[Any, ...]:
        return self._values()

    def __setstate__(self, state: tuple[Any, ...]) -> None:  # pickle and copy: fields set past the freeze
        for n, value in zip(self._fields, state):
            object.__setattr__(self, n, value)
