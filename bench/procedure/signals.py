"""Signals a procedure can name (``INSTRUMENT.COLUMN[.AXIS]``) and their units.

Each kind declares its signals once, with their units and roles (``Kind.signals``,
docs/instruments.md); a board whose frame description gives its own has a :class:`StreamSignals`
(``LabConfig.signals``). One lookup here serves the loader (units of bands and limits), the runner
(where to read a value, the units of a monitor column) and the readers.
"""

from __future__ import annotations

from dataclasses import dataclass

from bench.kinds import registry

AXES = ("x", "y", "z")


def default_kinds() -> dict[str, str]:
    """Instrument name -> kind assumed when no lab config is given: each installed kind's
    ``standard_name`` (the names of configs/sim.yaml)."""
    return registry.standard_kinds()


@dataclass(frozen=True)
class StreamSignals:
    """The signals of one instrument when its config gives its own (a board's frame description,
    ``LabConfig.signals``): column -> units, the columns that are x, y, z vectors, the commands the
    board has (step handlers need some: ``bit`` needs ``run_bit``), the description's name for
    messages, and column -> role (:data:`bench.kinds.record.ROLES`)."""

    columns: dict[str, str]
    vectors: tuple[str, ...]
    commands: frozenset[str] = frozenset()
    description: str = ""
    roles: tuple[tuple[str, str], ...] = ()


def kind_signals(kind: str | None) -> StreamSignals:
    """The signals kind ``kind`` declares, as a :class:`StreamSignals` (empty for an unknown kind)."""
    k = registry.get(kind or "")
    if k is None:
        return StreamSignals({}, ())
    return StreamSignals({s.name: s.units for s in k.signals}, tuple(s.name for s in k.signals if s.vector),
                         roles=tuple((s.name, s.role) for s in k.signals if s.role))


def parse_signal(signal: str) -> tuple[str, str, int | None]:
    """``acs_board.gyro.z`` -> ("acs_board", "gyro", 2); ``tvac.air_temp`` -> ("tvac", "air_temp", None)."""
    parts = signal.split(".")
    axis = None
    if len(parts) == 3 and parts[2] in AXES:
        axis = AXES.index(parts[2])
        parts = parts[:2]
    if len(parts) != 2 or not all(parts):
        raise KeyError(f"expected INSTRUMENT.COLUMN or INSTRUMENT.COLUMN.AXIS (axis x, y or z), got {signal!r}")
    return parts[0], parts[1], axis


def column_units(columns: dict[str, str], column: str) -> str | None:
    """Units of ``column`` among ``columns`` (a board's signals: exact names); None if absent."""
    return columns.get(column)


def _kind_units(kind: str | None, column: str) -> str | None:
    """Units of ``column`` as kind ``kind`` declares it (a pattern included); None if it does not."""
    k = registry.get(kind or "")
    s = k.signal(column) if k is not None else None
    return None if s is None else s.units


def signal_units(signal: str, kind: str | None, stream: StreamSignals | None = None) -> str:
    """Units of ``signal`` for an instrument of kind ``kind`` (with the signals its config gives,
    ``stream``, when it has its own); ``KeyError`` with a message if unknown."""
    inst, column, axis = parse_signal(signal)
    if kind is None:
        raise KeyError(f"the driver of instrument {inst!r} is unknown: validate with --config to check signal {signal!r}")
    sig = stream if stream is not None else kind_signals(kind)
    units = column_units(sig.columns, column) if stream is not None else _kind_units(kind, column)
    if units is None:
        k = registry.get(kind)
        known = ", ".join(s.shown for s in k.signals) if stream is None and k is not None else ", ".join(sig.columns)
        framed = f" (frame description {stream.description!r})" if stream is not None and stream.description else ""
        raise KeyError(f"{kind} {inst!r}{framed} has no signal {column!r} (signals: {known or 'none'})")
    vector = column in sig.vectors
    if vector and axis is None and column != "temp":
        raise KeyError(f"{signal!r} is a vector: name an axis, e.g. {signal}.z")
    if not vector and axis is not None:
        raise KeyError(f"{inst}.{column} is a scalar: it has no axis")
    return units


def monitor_units(column: str, kind: str | None) -> str:
    """The units a run file records for monitor column ``column`` of an instrument of kind ``kind``:
    its kind's declaration, ``1`` for a dimensionless one, ``""`` for a column the kind does not declare."""
    units = _kind_units(kind, column)
    return "" if units is None else (units or "1")


def role_of(column: str, kind: str | None, stream: StreamSignals | None = None) -> str:
    """The role column ``column`` plays for an instrument of kind ``kind`` (``""``: none)."""
    sig = stream if stream is not None else kind_signals(kind)
    roles = dict(sig.roles)
    if column in roles:
        return roles[column]
    k = registry.get(kind or "")
    s = k.signal(column) if k is not None else None
    return s.role if s is not None else ""
