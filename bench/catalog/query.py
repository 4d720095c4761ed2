"""Selecting catalogue rows: the filters of ``bench runs``, checked before any database is touched.

Text filters (unit serial, part, procedure, station) match exactly; a ``*`` in them matches any
run of characters. ``since`` keeps runs started at or after a UTC time; ``vacuum_below_torr`` runs
whose lowest monitored pressure was at or below that pressure (Torr). Rows come in start order
(oldest first), then by path; with a limit, the latest runs.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone

from pathlib import Path
from typing import Any

import sqlalchemy as sa

from bench.catalog.row import STATUSES, VERDICTS, run_row
from bench.catalog.schema import runs
from bench.catalog.store import Catalog
from bench.errors import InputError
from bench.record import layout
from bench.record.reader import STALE_AFTER_S
from bench.units import to_units

_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")


@dataclass(frozen=True)
class RunFilter:
    """What ``bench runs`` asks for; None means no condition. Times are naive UTC."""

    unit: str | None = None
    part: str | None = None
    procedure: str | None = None
    station: str | None = None
    status: str | None = None
    verdict: str | None = None
    mode: str | None = None
    """Stored mode (``hardware``, ``sim``, ``replay``, ``imported``; :func:`parse_mode`)."""
    since: datetime | None = None
    vacuum_below_torr: float | None = None
    limit: int | None = None


def parse_text(value: str | None, field: str) -> str | None:
    """A text filter: None stays None; an empty or blank value is bad input."""
    if value is None:
        return None
    if not value.strip():
        raise InputError("must not be empty", None, field)
    return value


def parse_status(value: str | None, field: str = "--status") -> str | None:
    """A status filter: one of :data:`bench.catalog.row.STATUSES`."""
    if value is None:
        return None
    if value not in STATUSES:
        raise InputError(f"expected one of {', '.join(STATUSES)}, got {value!r}", None, field)
    return value


def parse_verdict(value: str | None, field: str = "--verdict") -> str | None:
    """A verdict filter: one of :data:`bench.catalog.row.VERDICTS` (``no-verdict`` and
    ``no_verdict`` mean ``no verdict``)."""
    if value is None:
        return None
    v = re.sub(r"[-_ ]+", " ", value.strip().lower())
    if v not in VERDICTS:
        raise InputError(f"expected one of {', '.join(VERDICTS)} (or no-verdict), got {value!r}", None, field)
    return v


def parse_mode(value: str | None, field: str = "--mode") -> str | None:
    """A mode filter: ``real`` (or ``hardware``), ``dry-run`` (or ``sim``), ``replay``, ``imported``
    (:data:`bench.run_mode.FILTER_ALIASES`), as the stored mode."""
    from bench.run_mode import parse_mode as parse

    try:
        return parse(value)
    except ValueError as exc:
        raise InputError(str(exc), None, field) from None


def parse_since(value: str | None, now: datetime | None = None, field: str = "--since") -> datetime | None:
    """``--since``: a UTC date or time (``2026-11-23``, ``2026-11-23T08:00``, ``...Z``; a time
    with an offset is converted) or a duration back from ``now`` (``7 d``, ``12 h``, ``30 min``;
    units required). Returns a naive UTC datetime."""
    if value is None:
        return None
    text = value.strip()
    try:
        t = datetime.fromisoformat(text)
    except ValueError:
        pass
    else:
        return t.astimezone(timezone.utc).replace(tzinfo=None) if t.tzinfo is not None else t
    expected = "expected a UTC date or time (2026-11-23, 2026-11-23T08:00Z) or a duration with units (7 d, 12 h, 30 min)"
    if not text or _NUMBER.fullmatch(text):
        raise InputError(f"{expected}, got {value!r}", None, field)
    try:
        seconds = to_units(text, "s")
    except InputError as exc:
        raise InputError(f"{expected}, got {value!r} ({exc.message})", None, field) from None
    if seconds <= 0:
        raise InputError(f"the duration must be > 0, got {value!r}", None, field)
    now = now or datetime.now(timezone.utc).replace(tzinfo=None)
    try:
        return now - timedelta(seconds=seconds)
    except OverflowError:
        raise InputError(f"the duration {value!r} reaches back before year 1", None, field) from None


def parse_pressure(value: str | None, field: str = "--vacuum-below") -> float | None:
    """A pressure ("1e-5 Torr", "1e-3 mbar"; a bare number is Torr) as Torr, > 0."""
    if value is None:
        return None
    torr = to_units(value, "Torr", None, field)
    if torr <= 0:
        raise InputError(f"the pressure must be > 0, got {value!r}", None, field)
    return torr


MAX_LIMIT = 2**63 - 1
"""Largest row limit (SQLite's and PostgreSQL's largest integer)."""


def parse_limit(value: int | None, field: str = "--limit") -> int | None:
    """A row limit: None or 1 .. :data:`MAX_LIMIT`."""
    if value is not None and not 1 <= value <= MAX_LIMIT:
        raise InputError(f"must be between 1 and {MAX_LIMIT}, got {value}", None, field)
    return value


def _match(column: sa.ColumnElement, pattern: str) -> sa.ColumnElement:
    """``column = pattern``, or ``LIKE`` with ``*`` as the wildcard (SQL's own ``%``/``_`` literal)."""
    if "*" not in pattern:
        return column == pattern
    escaped = pattern.replace("\\", "\\\\").replace("%", "\\%").replace("_", "\\_").replace("*", "%")
    return column.like(escaped, escape="\\")


def select_runs(f: RunFilter) -> sa.Select:
    """The SELECT of every ``runs`` column for filter ``f``: oldest start first, or with a
    ``limit`` the latest ``limit`` runs, newest first (:func:`find_runs` puts them back in order)."""
    stmt = sa.select(runs)
    for column, value in ((runs.c.unit_serial, f.unit), (runs.c.unit_part, f.part),
                          (runs.c.procedure_name, f.procedure), (runs.c.station, f.station)):
        if value is not None:
            stmt = stmt.where(_match(column, value))
    if f.status is not None:
        stmt = stmt.where(runs.c.status == f.status)
    if f.verdict is not None:
        stmt = stmt.where(runs.c.verdict == f.verdict)
    if f.mode is not None:
        stmt = stmt.where(runs.c.mode == f.mode)
    if f.since is not None:
        stmt = stmt.where(runs.c.started_utc >= f.since)
    if f.vacuum_below_torr is not None:
        stmt = stmt.where(runs.c.min_pressure_torr <= f.vacuum_below_torr)
    if f.limit is not None:
        return stmt.order_by(runs.c.started_utc.desc(), runs.c.path.desc()).limit(f.limit)
    return stmt.order_by(runs.c.started_utc, runs.c.path)


def find_runs(cat: Catalog, f: RunFilter) -> list[dict[str, Any]]:
    """The rows of filter ``f``, oldest start first, after :func:`refresh_running` (not on a
    catalogue that is read-only here: its rows are listed as stored)."""
    if not cat.read_only:
        refresh_running(cat)
    rows = cat.select(select_runs(f))
    return rows[::-1] if f.limit is not None else rows


def refresh_running(cat: Catalog, *, stale_after_s: float = STALE_AFTER_S, now_unix: float | None = None) -> int:
    """Re-read the files of the rows still ``running`` that exist on this machine, and store what
    they say now: a writer that died leaves its row ``running`` until then, and the file reads
    ``crashed`` once its heartbeat is ``stale_after_s`` (s) old (a run that ended without updating
    the catalogue reads as it was closed). Unreadable or absent files leave their row alone, and so
    does a file that is not the run of the row (same path on another station of a shared
    catalogue: other start or procedure). Returns how many rows changed."""
    stale = cat.select(sa.select(runs.c.path, runs.c.started_utc, runs.c.procedure_name).where(runs.c.status == layout.STATUS_RUNNING))
    fresh = []
    for old in stale:
        path = Path(old["path"])
        if not path.is_file():
            continue
        try:
            row = run_row(path, stale_after_s=stale_after_s, now_unix=now_unix)
        except InputError:
            continue
        same_run = (row["started_utc"], row["procedure_name"]) == (old["started_utc"], old["procedure_name"])
        if same_run and row["status"] != layout.STATUS_RUNNING:
            fresh.append(row)
    return cat.upsert(fresh)
