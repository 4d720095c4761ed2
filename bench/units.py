"""Quantities with units, parsed by pint (never by hand).

Procedures and configs write "30 min", "100 Hz", "-29 degC", "1e-5 Torr". :func:`to_units` turns
such a value into a float in the unit the code works in, or raises an :class:`InputError` saying
what was expected.
"""

from __future__ import annotations

import functools
import math
import re
from pathlib import Path
from typing import Any


_NOT_FOR_PINT = ("dask", "scipy", "babel")
"""Optional packages pint imports, when installed, only to know they are there: dask (bench fleet
needs it; 60 ms), scipy (a bench dependency; 8-15 ms, used by nothing of pint outside its own
tests) and babel (locale-aware unit names, which bench never asks for; 2 ms). bench never gives pint
dask arrays, so all three are answered "absent" while pint is imported."""


def _import_pint_without_optional_lookups():  # noqa: ANN202 - returns the pint module
    """pint, imported with the packages of :data:`_NOT_FOR_PINT` that are not imported yet answered
    "absent" (a ``None`` entry in ``sys.modules`` for the time of the import): each stays
    importable afterwards."""
    import sys

    if "pint" in sys.modules:
        import pint as module
        return module
    hidden = [name for name in _NOT_FOR_PINT if name not in sys.modules]
    for name in hidden:
        sys.modules[name] = None  # type: ignore[assignment]
    try:
        import pint as module
    finally:
        for name in hidden:
            del sys.modules[name]
    return module


pint = _import_pint_without_optional_lookups()

from bench.errors import InputError, Location
from bench.user_cache import user_cache_dir


_DEG_ABSOLUTE = re.compile(r"(?<![A-Za-z_])(deg[CF]|degree_(?:Celsius|Fahrenheit)|celsius|fahrenheit)\b")

_NAME = r"[A-Za-z_\u00b0\u00b5\u03bc\u03a9%][A-Za-z0-9_\u00b0\u00b5\u03bc\u03a9%]*+(?:\s*+(?:\*\*|\^)\s*+[+-]?\d++(?:\.\d++)?)?+"
_OP = r"(?:\s*+[*/]\s*+|\s++)"
_TERM = rf"(?:{_NAME}|\(\s*+{_NAME}(?:{_OP}{_NAME})*+\s*+\))"


@functools.lru_cache(maxsize=1)
def _quantity_text() -> re.Pattern[str]:
    """A quantity as text: one number, then unit names joined by ``*``, ``/`` and exponents
    (``-29 degC``, ``1e-5 Torr``, ``0.04 g^2/Hz``, ``20 deg/s**2``). Anything else (``66 degC * 0``,
    ``10 min + 5 s``) would be evaluated by pint as an expression: it is refused, not computed.
    Compiled on first use (a few ms a command that reads no quantity need not pay)."""
    return re.compile(
        r"\s*+[+-]?(?:\d++\.?\d*+|\.\d++)(?:[eE][+-]?\d++)?+"  # one number, first
        rf"(?:\s*+/?\s*+{_TERM}(?:{_OP}{_TERM})*+)?+\s*+"  # then unit names joined by * and /, each with an exponent
    )


TEMPERATURE_DIFFERENCE = "delta_degC"
"""Units of temperature differences (bands) and, as ``delta_degC/min``, of temperature rates."""


@functools.lru_cache(maxsize=1)
def registry() -> pint.UnitRegistry:
    """The one pint registry of the application (offset units like degC allowed as plain values).

    pint's parsed unit definitions are cached in :func:`unit_cache_dir` (pint's own disk cache,
    named by the definition file's content, pint's and Python's versions): building the registry
    then takes ~25 ms instead of ~350 ms, which is most of a ``bench validate``. A cache that
    cannot be used (read-only home, a damaged file) is removed where possible and the registry is
    built without it.
    """
    try:
        ureg = pint.UnitRegistry(autoconvert_offset_to_baseunit=True, cache_folder=unit_cache_dir())
    except Exception:  # noqa: BLE001 - the cache is an optimisation: any failure means "build it again"
        import shutil

        shutil.rmtree(unit_cache_dir(), ignore_errors=True)
        ureg = pint.UnitRegistry(autoconvert_offset_to_baseunit=True)
    ureg.define("Torr = atm / 760")  # vacuum gauges report Torr; pint only knows 'torr'
    return ureg


def unit_cache_dir() -> Path:
    """Where pint's parsed definitions are cached: ``$XDG_CACHE_HOME/bench/pint`` (default
    ``~/.cache/bench/pint``)."""
    return user_cache_dir("pint")


def to_units(value: Any, units: str, location: Location | None = None, field: str | None = None) -> float:
    """Convert ``value`` ("30 min", "100 Hz", a bare number meaning ``units``) to a float in ``units``.

    Raises :class:`InputError` for text that is not a quantity or has the wrong dimension.
    """
    if isinstance(value, bool):
        raise InputError(f"expected a quantity in {units}, got {value!r}", location, field)
    if isinstance(value, (int, float)):
        if not math.isfinite(value):
            raise InputError(f"{value!r} is not a finite quantity", location, field)
        return float(value)
    if not isinstance(value, str):
        raise InputError(f"expected a quantity in {units} such as '10 {units}', got {value!r}", location, field)
    try:
        return _text_in_units(value, units)
    except _Unreadable as exc:
        raise InputError(str(exc), location, field) from None


class _Unreadable(Exception):
    """A quantity's text that cannot be read in the units asked (the message says why)."""


@functools.lru_cache(maxsize=4096)
def _text_in_units(value: str, units: str) -> float:
    """``value`` (text) as a float in ``units``; raises :class:`_Unreadable`. Cached: a procedure
    writes the same few quantities many times (``estcube_gyro_thermal``: 189 conversions of 22
    texts), and pint's parser costs ~0.2 ms a call. Only results are cached, never errors."""
    if len(value) > 200 or not _quantity_text().fullmatch(value):
        raise _Unreadable(f"cannot read quantity {value[:60]!r}: expected a number then its units, such as '10 {units}' "
                          "(expressions are not evaluated)")
    if "delta_deg" in units:
        # a temperature difference or rate ("0.5 degC", "0.5 degC/min"): degC means a difference
        # here, not 0.5 °C = 273.65 K
        value = _DEG_ABSOLUTE.sub(r"delta_\1", value)
    ureg = registry()
    try:
        q = ureg.Quantity(value.strip())
    except Exception as exc:  # noqa: BLE001 - pint's parser raises many types (even AssertionError)
        raise _Unreadable(f"cannot read quantity {value!r}: {_short(exc)}") from None
    try:
        if not isinstance(q, pint.Quantity):  # a bare number in a string
            result = float(q)
        else:
            result = float(q.to(units).magnitude)
    except pint.errors.DimensionalityError:
        raise _Unreadable(f"{value!r} has units of {q.dimensionality}, expected a quantity convertible to {units}") from None
    except Exception as exc:  # noqa: BLE001 - e.g. a complex or non-numeric magnitude
        raise _Unreadable(f"cannot read quantity {value!r}: {_short(exc)}") from None
    if not math.isfinite(result):
        raise _Unreadable(f"{value!r} is not a finite quantity")
    return result


def quantity_units(value: Any) -> str | None:
    """The units of ``value`` when it is text written as a quantity with units (``-29 degC``,
    ``5 %``, ``0.4 deg/s``), else None (a bare number, other text)."""
    if not isinstance(value, str) or len(value) > 200 or not _quantity_text().fullmatch(value):
        return None
    try:
        q = registry().Quantity(value.strip())
    except Exception:  # noqa: BLE001 - pint's parser raises many types
        return None
    if not isinstance(q, pint.Quantity) or q.unitless and "%" not in value and "percent" not in value:
        return None
    written = re.sub(r"^\s*[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?\s*", "", value).strip()
    return written or str(q.units)  # as the file writes it: degC, not degree_Celsius


def _short(exc: Exception) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__
