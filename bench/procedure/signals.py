"""Signals a procedure can name (``INSTRUMENT.COLUMN[.AXIS]``) and their units, per driver.

Polled instruments log their ``monitor()`` columns; the sensor board streams vectors. One table
here serves the loader (units of bands and limits) and the runner (where to read a value).
"""

from __future__ import annotations

from dataclasses import dataclass

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
"""The default board's signals (ours, drivers/frames/acs_board.yaml; tests/test_frame_descriptions.py
checks the two agree). A board with a frame description of its own has its :class:`StreamSignals`."""
AXES = ("x", "y", "z")


@dataclass(frozen=True)
class StreamSignals:
    """The signals of one board's data stream, from its frame description (``LabConfig.signals``):
    column -> units, the columns that are x, y, z vectors, the commands the board has (step
    handlers need some: ``bit`` needs ``run_bit``), and the description's name for messages."""

    columns: dict[str, str]
    vectors: tuple[str, ...]
    commands: frozenset[str] = frozenset()
    description: str = ""


STEP_COMMANDS = {"power": ("sensor_power",), "bit": ("run_bit",), "odr": ("set_odr",), "moving_average": ("set_moving_avg",)}
"""A board step (or a ``configure`` parameter) -> the commands its handler sends (drivers/board_frames.OPS)."""


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


def signal_units(signal: str, kind: str | None, stream: StreamSignals | None = None) -> str:
    """Units of ``signal`` for an instrument with driver ``kind`` (a board: with the signals of its
    frame description, ``stream``); ``KeyError`` with a message if unknown."""
    inst, column, axis = parse_signal(signal)
    if kind is None:
        raise KeyError(f"the driver of instrument {inst!r} is unknown: validate with --config to check signal {signal!r}")
    columns = stream.columns if stream is not None else SIGNALS.get(kind, {})
    vectors = stream.vectors if stream is not None else VECTOR_COLUMNS.get(kind, ())
    if column in columns:
        units = columns[column]
    elif "ch*" in columns and column.startswith("ch") and column[2:].isdigit() and 101 <= int(column[2:]) <= 399:
        units = columns["ch*"]
    else:
        known = ", ".join(c.replace("*", "NNN") for c in columns) or "none"
        framed = f" (frame description {stream.description!r})" if stream is not None and stream.description else ""
        raise KeyError(f"{kind} {inst!r}{framed} has no signal {column!r} (signals: {known})")
    vector = column in vectors
    if vector and axis is None and column != "temp":
        raise KeyError(f"{signal!r} is a vector: name an axis, e.g. {signal}.z")
    if not vector and axis is not None:
        raise KeyError(f"{inst}.{column} is a scalar: it has no axis")
    return units
