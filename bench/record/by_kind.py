"""A run file's streams by kind and role, never by instrument name.

Every instrument's group in a run file records its kind (``/instruments/NAME`` attribute ``driver``,
docs/run-file.md); its kind's record says what each column is (``Signal.role``: the chamber's air
temperature, the table's rate, the board's gyro; bench.kinds.record.ROLES). Readers, analysis,
report, web and catalogue ask here for "the columns with role R in this run" whatever the lab
named its instruments (a board called ``imu``, a chamber ``chamber1``), and get every instrument of
a kind (two loggers, two supplies).

A file that does not record an instrument's kind (written before the attribute existed, or by
other software) is read with the kind of the standard instrument of the same name, if any.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterable

from bench.kinds import registry
from bench.kinds.record import Kind, Signal
from bench.record.layout import MONITOR_STREAM, split_stream_key


@dataclass(frozen=True)
class RoleColumn:
    """Column ``column`` of stream ``key`` (instrument ``instrument`` of kind ``kind``) plays a role;
    ``label`` is what a report calls it (its kind's, with the instrument's name when the run has
    several instruments of that kind), ``signal`` its kind's declaration."""

    key: str
    instrument: str
    kind: str
    column: str
    units: str
    label: str
    signal: Signal
    monitor: bool


def instrument_kinds(instruments: dict[str, dict[str, Any]]) -> dict[str, str]:
    """Instrument name -> kind recorded for it (``driver``), or the standard name's kind."""
    standard = registry.standard_kinds()
    out = {}
    for name, attrs in instruments.items():
        kind = str((attrs or {}).get("driver", "") or standard.get(name, ""))
        if kind:
            out[name] = kind
    return out


def role_columns(summary: Any, role: str | Iterable[str]) -> list[RoleColumn]:
    """Every column of ``summary``'s streams (a :class:`bench.record.reader.RunSummary`) whose kind
    gives it role ``role`` (or one of several), in stream order. Columns of an instrument whose kind is
    not installed here are left out."""
    roles = {role} if isinstance(role, str) else set(role)
    kinds = instrument_kinds(summary.instruments)
    per_kind: dict[str, int] = {}
    for k in kinds.values():
        per_kind[k] = per_kind.get(k, 0) + 1
    out = []
    for st in summary.streams:
        instrument, stream = split_stream_key(st.key)
        kind = registry.get(kinds.get(instrument, ""))
        if kind is None or stream not in ("", MONITOR_STREAM):
            continue
        for column, units in st.columns.items():
            sig = kind.signal(column)
            if sig is None or sig.role not in roles:
                continue
            out.append(RoleColumn(st.key, instrument, kind.name, column, units, _label(sig, column, instrument, per_kind[kind.name] > 1),
                                  sig, stream == MONITOR_STREAM))
    return out


def first(summary: Any, role: str) -> RoleColumn | None:
    """The first column with role ``role`` (:func:`role_columns`), or None."""
    found = role_columns(summary, role)
    return found[0] if found else None


def streaming(summary: Any) -> list[tuple[str, Kind]]:
    """(stream key, kind) of the data streams of instruments whose kind streams (a board), in order."""
    kinds = instrument_kinds(summary.instruments)
    out = []
    for st in summary.streams:
        instrument, stream = split_stream_key(st.key)
        kind = registry.get(kinds.get(instrument, ""))
        if kind is not None and kind.streams and stream == "":
            out.append((st.key, kind))
    return out


def _label(sig: Signal, column: str, instrument: str, several: bool) -> str:
    label = (sig.label or column).replace("{column}", column)
    return f"{instrument}: {label}" if several else label
