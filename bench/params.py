"""Build parameter dataclasses from plain mappings (model and world files), and check a procedure
parameter's command-line override (``-p NAME=VALUE``) against its default."""

from __future__ import annotations

from dataclasses import fields
from typing import TYPE_CHECKING, Any, TypeVar

if TYPE_CHECKING:  # pragma: no cover
    from bench.errors import InputError

T = TypeVar("T")


def dataclass_from_dict(cls: type[T], data: dict[str, Any]) -> T:
    """``cls(**data)``, but unknown keys raise ``KeyError`` listing them (the loader locates it)."""
    names = {f.name for f in fields(cls)}  # type: ignore[arg-type]
    unknown = set(data) - names
    if unknown:
        raise KeyError(", ".join(sorted(unknown)))
    return cls(**data)


def override_problem(name: str, default: Any, value: Any) -> "InputError | None":
    """Why ``-p NAME=VALUE`` cannot stand for a parameter whose default is ``default``: a default
    written as a quantity (``-29 degC``, ``5 %``, a list of them) needs a value of the same kind of
    quantity, checked here, before the value reaches the steps that use it, so the message names
    ``-p NAME`` (not the step's line in the procedure file). None when it can stand, or when the
    default is no quantity (text, numbers: the steps check those)."""
    from bench.errors import InputError
    from bench.units import quantity_units

    field = f"-p {name}"
    defaults = default if isinstance(default, list) else [default]
    values = value if isinstance(value, list) else [value]
    units = next((u for u in (quantity_units(d) for d in defaults) if u), None)
    if units is None:
        return None
    for v in values:
        if isinstance(v, bool) or not isinstance(v, (str, int, float)):
            return InputError(f"expected a quantity such as {defaults[0]}, got {v!r}", None, field)
        if isinstance(v, (int, float)):
            continue  # a bare number is in the parameter's units, as everywhere
        try:
            from bench.units import to_units

            to_units(v, units, None, field)
        except InputError as exc:
            return InputError(f"{exc.message} (the default is {defaults[0]}; write the value with its units, "
                              f"e.g. -p {name}={str(defaults[0]).replace(' ', '')})", None, field)
    return None
