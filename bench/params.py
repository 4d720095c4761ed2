"""Build parameter dataclasses from plain mappings (model and world files)."""

from __future__ import annotations

from dataclasses import fields
from typing import Any, TypeVar

T = TypeVar("T")


def dataclass_from_dict(cls: type[T], data: dict[str, Any]) -> T:
    """``cls(**data)``, but unknown keys raise ``KeyError`` listing them (the loader locates it)."""
    names = {f.name for f in fields(cls)}  # type: ignore[arg-type]
    unknown = set(data) - names
    if unknown:
        raise KeyError(", ".join(sorted(unknown)))
    return cls(**data)
