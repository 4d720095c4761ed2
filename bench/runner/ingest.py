"""Stream ingest: frames of the streaming instruments into the run file and the recording windows.

Each :meth:`StreamIngest.drain` polls one streaming instrument, maps its board time to run time
(``time`` = board time + an offset fixed by the first batch of a recording window, whose newest
frame is taken to have arrived just now), appends the rows (plus the compensated gyro when the
board has a calibration), counts link errors, and feeds the open windows.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Callable

import numpy as np

from bench.record import Column, RunRecorder
from bench.runner.instruments import Streaming
from drivers.board_frames import FrameDescription
from drivers.frame_schema import builtin_description

if TYPE_CHECKING:  # pragma: no cover
    from bench.clock import Clock
    from bench.runner.windows import Windows

COMPENSATED_COLUMN = Column("gyro_comp", "deg/s", "f8", (3,))
"""Added when the board has a calibration: the gyro rates compensated with NPSAT1 Eq. 2."""


def board_columns(description: "FrameDescription | None") -> list[Column]:
    """The run-file columns of a board's data stream from its frame description (ours when None):
    ``counter``, ``board_time`` (s), the signals in their units, ``status``."""
    return [Column(*c) for c in (description or builtin_description()).stream_columns()]


ACS_COLUMNS = board_columns(None)
"""Stream layout of our sensor board: temp = (gyro die, accel die, board) (docs/acs-board-protocol.md)."""


def stream_columns(drv: Streaming) -> list[Column]:
    """The run-file columns of ``drv``'s data stream (:meth:`Streaming.stream_columns`)."""
    return [Column(name, units, dtype, shape) for name, units, dtype, shape in drv.stream_columns()]


class StreamIngest:
    """The streaming instruments of one run: declared streams, counters, latest frames."""

    def __init__(self, rec: RunRecorder, clock: "Clock", windows: "Windows", step: Callable[[], int]):
        self.rec = rec
        self.clock = clock
        self.windows = windows
        self._step = step
        self.keys: dict[str, str] = {}
        """Instrument -> run-file stream key."""
        self.stats: dict[str, dict[str, int]] = {}
        self.streaming: set[str] = set()
        """Instruments whose recording window is open (drained while the runner waits)."""
        self._time_offset: dict[str, float | None] = {}
        self._last: dict[str, dict[str, np.ndarray]] = {}
        self._last_gyro_mean: dict[str, np.ndarray] = {}
        self.last_frame_t: dict[str, float] = {}
        """Run time of the newest frame of each instrument (s), for the stall interlocks."""

    def declare(self, name: str, drv: Streaming) -> None:
        """Declare the stream of ``name`` in the run file (before recording starts)."""
        comp = drv.compensation
        self.keys[name] = self.rec.add_stream(name, stream_columns(drv) + ([COMPENSATED_COLUMN] if comp is not None else []))
        self.stats[name] = {"frames": 0, "crc_errors": 0, "dropped_frames": 0, "garbage_bytes": 0}
        self._time_offset[name] = None

    def begin(self, name: str) -> None:
        """A recording window of ``name`` opens: the next batch fixes the board-time offset."""
        self._time_offset[name] = None
        self.streaming.add(name)
        self.last_frame_t[name] = self.clock.now()

    def end(self, name: str) -> None:
        self.streaming.discard(name)

    def drain(self, name: str, drv: Streaming) -> int:
        """Poll ``drv`` (instrument ``name``) and append its decoded frames; returns rows."""
        batch = drv.poll()
        stats = self.stats[name]
        layout = batch.layout_errors
        if batch.crc_errors or batch.dropped_frames or batch.garbage_bytes or layout:
            self.rec.event(
                "stream", name,
                f"link errors: {batch.crc_errors} CRC errors, {batch.dropped_frames} dropped frames, {batch.garbage_bytes} garbage bytes"
                + (f", {layout} frames whose constant fields differ from the frame description" if layout else ""),
                t_s=self.clock.now(), step=self._step(),
            )
        stats["crc_errors"] += batch.crc_errors
        stats["dropped_frames"] += batch.dropped_frames
        stats["garbage_bytes"] += batch.garbage_bytes
        n = batch.counter.shape[0]
        if n == 0:
            return 0
        if self._time_offset[name] is None:
            self._time_offset[name] = self.clock.now() - float(batch.board_time_s[-1])
        time_s = batch.board_time_s + self._time_offset[name]
        extra = {"gyro_comp": drv.compensated_gyro(batch)} if drv.compensation is not None else {}
        columns = batch.columns
        self.rec.append(self.keys[name], time_s, counter=batch.counter, board_time=batch.board_time_s, status=batch.status,
                        **columns, **extra)
        stats["frames"] += n
        self.last_frame_t[name] = float(time_s[-1])
        self._last[name] = {c: v[-1] for c, v in columns.items()}
        if "gyro" in columns:
            self._last_gyro_mean[name] = columns["gyro"].mean(axis=0)
        if self.windows.any_open:
            for c, v in columns.items():
                if v.ndim == 1:
                    self.windows.feed(f"{name}.{c}", time_s, v)
                    continue
                if v.shape[1] == 3:
                    for k, axis in enumerate("xyz"):
                        self.windows.feed(f"{name}.{c}.{axis}", time_s, v[:, k])
                if c == "temp":
                    self.windows.feed(f"{name}.temp", time_s, v[:, 0])  # the temperatures named without an axis: the gyro's
        return n

    def latest(self, name: str, column: str, axis: int | None) -> float:
        """Newest value of ``name.column[.axis]``; NaN before the first frame."""
        last = self._last.get(name, {}).get(column)
        return float("nan") if last is None else float(np.ravel(last)[axis if axis is not None else 0])

    def readings(self) -> list[str]:
        """One progress fragment per streaming instrument (mean gyro of the last batch, gyro die temperature)."""
        parts = []
        for name in self.streaming:
            g = self._last_gyro_mean.get(name)
            if g is not None:
                t = self._last.get(name, {}).get("temp")
                t0 = None if t is None else float(np.ravel(t)[0])
                parts.append(f"gyro {g[0]:+.3f} {g[1]:+.3f} {g[2]:+.3f} deg/s" + (f", {t0:.1f} degC" if t0 is not None else ""))
        return parts
