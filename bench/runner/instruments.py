"""What the runner needs from an instrument: small Protocols instead of attribute probing.

Drivers satisfy them structurally (they import nothing from bench). Every driver is an
:class:`Instrument`; one that is read periodically is also :class:`Polled`; one that streams
frames (the sensor board) is :class:`Streaming`. The step handlers reach instrument-specific
commands (``set_point``, ``set_rate``…) only for the kinds the procedure validator allowed for
that step.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Instrument(Protocol):
    """Every driver: identified at the start of a run, brought to its safe state on abort."""

    kind: str
    streams: bool
    baudrate: int | None

    def identify(self) -> dict[str, str]:
        """Identity strings (model, serial, firmware…) recorded in the run file."""

    def safe_state(self) -> str:
        """Put the instrument where nothing can be harmed (heaters off, table stopped…); returns
        what it was told, for the run file's ``safe_state`` event."""

    def close(self) -> None:
        """Release the link."""


@runtime_checkable
class Polled(Protocol):
    """An instrument read at its poll interval; each reading is one row of ``/streams/NAME/monitor``."""

    def monitor_columns(self) -> list[str]:
        """The column of each reading (its units are the kind's: ``Kind.signals``); also sets the
        instrument up for polling."""

    def monitor(self) -> dict[str, float]:
        """One reading of every column (NaN where the instrument has no valid value)."""


class FrameBatch(Protocol):
    """Decoded frames of one poll of a streaming instrument (``drivers.frame_decoder.DecodedBatch``):
    counter, board time (s) and status per row, and the board's signal columns by name, in the
    units of its frame description."""

    counter: np.ndarray
    board_time_s: np.ndarray
    status: np.ndarray
    columns: dict[str, np.ndarray]
    crc_errors: int
    garbage_bytes: int
    dropped_frames: int
    layout_errors: int


@runtime_checkable
class Streaming(Protocol):
    """An instrument that streams sensor frames while a recording window is open."""

    compensation: Any
    """The board's calibration (``describe()``, used by ``compensated_gyro``) or None."""

    def start_stream(self) -> None: ...

    def stop_stream(self) -> None: ...

    def poll(self) -> FrameBatch:
        """Every frame received since the last poll."""

    def stream_columns(self) -> list[tuple[str, str, str, tuple[int, ...]]]:
        """``(name, units, dtype, row shape)`` of the recorded columns of its data stream."""

    def compensated_gyro(self, batch: FrameBatch) -> np.ndarray:
        """Gyro rates of ``batch`` with the board's calibration applied (deg/s, (n, 3))."""

    def get_config(self) -> dict:
        """The board's configuration; ``streaming`` says whether it is sending frames."""


def link_baudrate(drv: Instrument) -> str:
    """The serial bit rate of ``drv``'s link as recorded in the run file ("" when not serial;
    drivers derive from ``drivers.base.Driver``, whose ``baudrate`` is None off a serial port)."""
    rate = drv.baudrate
    return "" if rate is None else str(rate)
