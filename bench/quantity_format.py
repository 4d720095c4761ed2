"""One formatter for a number with its unit: every view of a run (``bench run``'s summary and
progress line, ``bench plan``, ``bench inspect``, ``bench watch``, ``bench runs``, the HTML report,
the web station, ``bench unit``) writes quantities through these functions, so a value reads the same
everywhere: ``40.69 degC``, ``760 Torr``, ``1.2e-05 Torr``, ``-5 .. 5 %``, ``0x0637``.

Rules:

* a number keeps ``digits`` significant digits (default 4), trailing zeros dropped; whole numbers
  stay whole (``760``, never ``7.6e+02``); scientific notation only below 1e-3 or from 1e5 on;
* units follow after one space; dimensionless values (``""``, ``"1"``) have none; a temperature
  difference (``delta_degC``) reads ``degC``;
* scale-factor errors and other fractions shown as percent are converted by the caller's
  statistic (:func:`bench.record.checks.display_value`), never here: percent limits stay percent
  because the same value and limits pass through the same conversion;
* status words (columns named ``*status*``) are bit fields: hexadecimal, never averaged or scaled
  (:func:`is_status_column`);
* a missing value is ``-``.

Light on purpose (the standard library only): every layer may use it.
"""

from __future__ import annotations

import math
import re
from typing import Any

MISSING = "-"
"""What a missing value (None) reads."""

DIMENSIONLESS = ("", "1", "dimensionless")


def unit_text(units: str | None) -> str:
    """Units as shown: ``""`` for dimensionless, ``delta_degC`` as ``degC``, a power as a
    superscript (``deg/s**2`` as ``deg/s²``, ``g^2/Hz`` as ``g²/Hz``), else as given."""
    u = (units or "").strip()
    if u in DIMENSIONLESS:
        return ""
    return _POWER.sub(lambda m: m.group(1).translate(_SUPERSCRIPT), u.replace("delta_", ""))


_POWER = re.compile(r"\s*(?:\*\*|\^)\s*(-?\d+)")
_SUPERSCRIPT = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")


def is_status_column(name: str) -> bool:
    """Whether column ``name`` holds a status word (a bit field: shown in hex, never averaged)."""
    return "status" in name.lower()


def fmt_number(value: Any, digits: int = 4) -> str:
    """``value`` with ``digits`` significant digits: ``40.69``, ``760``, ``-0.3483``, ``1.2e-05``;
    ``-`` for None, ``nan``/``inf`` as such; booleans and text as text."""
    if value is None:
        return MISSING
    if isinstance(value, bool) or isinstance(value, str):
        return str(value)
    try:
        x = float(value)
    except (TypeError, ValueError):
        return str(value)
    if math.isnan(x):
        return "nan"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    if x == 0:
        return "0"
    digits = max(1, int(digits))
    a = abs(x)
    if x.is_integer() and a < 1e9:
        return str(int(x))
    if a < 1e-3 or a >= 1e5:
        mantissa, _, exponent = f"{x:.{digits - 1}e}".partition("e")
        return f"{_strip(mantissa)}e{exponent}"
    decimals = max(0, digits - 1 - math.floor(math.log10(a)))
    text = _strip(f"{x:.{decimals}f}")
    return "0" if text in ("-0", "") else text


def _strip(text: str) -> str:
    return text.rstrip("0").rstrip(".") if "." in text else text


def fmt_quantity(value: Any, units: str | None = "", digits: int = 4, *, signed: bool = False) -> str:
    """``40.69 degC``: :func:`fmt_number` then the units (:func:`unit_text`); ``-`` alone for None.
    ``signed``: a ``+`` before positive values (rates, offsets)."""
    text = fmt_number(value, digits)
    if text == MISSING:
        return MISSING
    if signed and not text.startswith("-") and text not in ("0", "nan"):
        text = "+" + text
    u = unit_text(units)
    if u == "%":
        return f"{text} %"
    return f"{text} {u}" if u else text


def fmt_range(low: Any, high: Any, units: str | None = "", digits: int = 4) -> str:
    """Limits with their units once: ``-33 .. 70 degC``, ``≥ 3 deg/s``, ``≤ 0.5 %``; ``none``
    when neither side is set."""
    u = unit_text(units)
    tail = f" {u}" if u else ""
    lo = None if low is None or _infinite(low) else fmt_number(low, digits)
    hi = None if high is None or _infinite(high) else fmt_number(high, digits)
    if lo is not None and hi is not None:
        return f"{lo} .. {hi}{tail}"
    if lo is not None:
        return f"≥ {lo}{tail}"
    if hi is not None:
        return f"≤ {hi}{tail}"
    return "none"


def _infinite(v: Any) -> bool:
    try:
        return math.isinf(float(v))
    except (TypeError, ValueError):
        return False


def fmt_status_word(value: Any) -> str:
    """A status word as ``0x0637`` (at least four hex digits); ``-`` for None or a non-integer."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        return MISSING
    if not math.isfinite(x) or not x.is_integer() or x < 0:
        return fmt_number(x)
    return f"0x{int(x):04x}"


def fmt_reading(value: Any, units: str | None, column: str = "", *, integer: bool = False, digits: int = 5) -> str:
    """A reading of ``column``: a status word in hex, an integer column whole, else
    :func:`fmt_quantity` (``digits`` significant digits)."""
    if is_status_column(column):
        return fmt_status_word(value)
    if integer and value is not None:
        try:
            return fmt_quantity(int(value), units)
        except (TypeError, ValueError, OverflowError):
            pass
    return fmt_quantity(value, units, digits)


def fmt_hms(seconds: float | None) -> str:
    """A run time or duration (s) as ``H:MM:SS`` (rounded to the second); ``-`` when unknown."""
    if seconds is None:
        return MISSING
    try:
        s = float(seconds)
    except (TypeError, ValueError):
        return MISSING
    if not math.isfinite(s):
        return MISSING
    n = int(round(s))
    sign = "-" if n < 0 else ""
    n = abs(n)
    return f"{sign}{n // 3600}:{n // 60 % 60:02d}:{n % 60:02d}"


def fmt_seconds(seconds: float | None) -> str:
    """A short duration with its unit for prose: ``45 s``, ``12.5 min``, ``2.25 h``."""
    if seconds is None:
        return MISSING
    s = float(seconds)
    if not math.isfinite(s):
        return fmt_number(s)
    if abs(s) < 120:
        return fmt_quantity(s, "s", 3)
    if abs(s) < 2 * 3600:
        return fmt_quantity(s / 60.0, "min", 3)
    return fmt_quantity(s / 3600.0, "h", 3)
