"""Signals a procedure can name (``INSTRUMENT.COLUMN[.AXIS]``) and their units, per driver.

Polled instruments log their ``monitor()`` columns; the sensor board streams vectors. One table
here serves the loader (units of bands and limits) and the runner (where to read a value).
"""

from __future__ import annotations

DEFAULT_KINDS = {
    "acs_board": "acs_board",
    "stepper_bench": "stepper_bench",
    "thermocouples": "thermocouple_reader",
    "tvac": "tvac",
    "rate_table": "rate_table",
}
"""Instrument name -> driver assumed when no lab config is given (the names of configs/sim.yaml)."""

SIGNALS: dict[str, dict[str, str]] = {
    "acs_board": {"gyro": "deg/s", "accel": "g_n", "mag": "uT", "temp": "degC"},
    "tvac": {"air_temp": "degC", "mount_temp": "degC", "pressure": "Torr"},
    "thermocouple_reader": {"ch*": "degC"},
    "rate_table": {"angle": "deg", "rate": "deg/s", "tilt": "deg", "statusword": "", "tilt_statusword": ""},
    "stepper_bench": {"angle": "deg", "rate": "deg/s"},
}
"""Driver -> column -> units. ``ch*``: any thermocouple channel ``ch101``..``ch399``."""

VECTOR_COLUMNS = {"acs_board": ("gyro", "accel", "mag", "temp")}
AXES = ("x", "y", "z")


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


def signal_units(signal: str, kind: str | None) -> str:
    """Units of ``signal`` for an instrument with driver ``kind``; ``KeyError`` with a message if unknown."""
    inst, column, axis = parse_signal(signal)
    if kind is None:
        raise KeyError(f"the driver of instrument {inst!r} is unknown: validate with --config to check signal {signal!r}")
    columns = SIGNALS.get(kind, {})
    if column in columns:
        units = columns[column]
    elif "ch*" in columns and column.startswith("ch") and column[2:].isdigit() and 101 <= int(column[2:]) <= 399:
        units = columns["ch*"]
    else:
        known = ", ".join(c.replace("*", "NNN") for c in columns) or "none"
        raise KeyError(f"{kind} {inst!r} has no signal {column!r} (signals: {known})")
    vector = column in VECTOR_COLUMNS.get(kind, ())
    if vector and axis is None and column != "temp":
        raise KeyError(f"{signal!r} is a vector: name an axis, e.g. {signal}.z")
    if not vector and axis is not None:
        raise KeyError(f"{inst}.{column} is a scalar: it has no axis")
    return units
