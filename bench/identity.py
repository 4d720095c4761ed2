"""Identity of what is tested where: checks of the unit serial/part/revision and station names,
and of instrument calibration due dates (``docs/units-under-test.md``).

Bottom layer (imports only :mod:`bench.errors`): the lab config checks ``station:`` and
``calibration_due:`` with these functions, ``bench run`` its ``--unit``, ``--part``,
``--revision`` and ``--station`` options.

Dates are calendar dates in UTC (a calibration is due *on* a day, compared with today's UTC date).
"""

from __future__ import annotations

import re
import socket
from dataclasses import dataclass
from datetime import date, datetime, timezone

from bench.errors import InputError, Location

MAX_IDENTITY_CHARS = 64
"""Longest unit serial, part number, revision or station name (characters)."""

ISO_DATE_RE = re.compile(r"^\d{4}-\d{2}-\d{2}$")
"""A calendar date as ``YYYY-MM-DD`` (ISO 8601 extended form, nothing else)."""


@dataclass(frozen=True)
class RunIdentity:
    """The unit under test and the station of one run; ``""`` where not given."""

    unit_serial: str = ""
    unit_part: str = ""
    unit_revision: str = ""
    station: str = ""


def identity_text_problem(value: str) -> str:
    """Why ``value`` cannot be a serial, part number, revision or station name, ``""`` if it can:
    it must be non-empty, at most :data:`MAX_IDENTITY_CHARS` characters, printable, without
    control characters and without leading or trailing white space."""
    if not value:
        return "must not be empty"
    if len(value) > MAX_IDENTITY_CHARS:
        return f"is {len(value)} characters long; at most {MAX_IDENTITY_CHARS} are allowed"
    bad = next((c for c in value if not c.isprintable()), None)
    if bad is not None:
        return f"contains the control or non-printable character {bad!r}; only printable characters are allowed"
    if value != value.strip():
        return "has leading or trailing white space"
    return ""


def check_identity_text(value: object, location: Location | None, field: str) -> str:
    """``value`` if it is a valid identity text (see :func:`identity_text_problem`), else raise a
    located :class:`InputError` naming ``field`` (a config key or a command-line option)."""
    if not isinstance(value, str):
        raise InputError(f"expected text such as SN12, got {type(value).__name__} {value!r}", location, field)
    problem = identity_text_problem(value)
    if problem:
        raise InputError(f"{value!r} {problem}", location, field)
    return value


def parse_iso_date(value: object, location: Location | None, field: str) -> date:
    """A ``YYYY-MM-DD`` calendar date (a YAML date, written unquoted, arrives as that text);
    anything else raises a located :class:`InputError`."""
    text = value.isoformat() if isinstance(value, date) else value
    if not isinstance(text, str) or not ISO_DATE_RE.match(text):
        raise InputError(f"expected a date YYYY-MM-DD such as 2027-03-31, got {value!r}", location, field)
    try:
        return date.fromisoformat(text)
    except ValueError as exc:
        raise InputError(f"{text!r} is not a calendar date ({exc})", location, field) from None


def utc_today() -> date:
    """Today's date in UTC."""
    return datetime.now(timezone.utc).date()


def default_station() -> str:
    """The station name when neither ``--station`` nor the config's ``station:`` gives one: the host
    name, cut to :data:`MAX_IDENTITY_CHARS` characters (``unknown`` if it has none)."""
    name = "".join(c for c in socket.gethostname() if c.isprintable()).strip()
    return name[:MAX_IDENTITY_CHARS] or "unknown"
