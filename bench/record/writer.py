"""Crash-safe HDF5 run recorder: one file per run, written in SWMR mode.

The whole file layout (root attributes, texts, instrument groups, stream datasets, events table,
heartbeat; names in :mod:`bench.record.layout`) is created first; :meth:`RunRecorder.start` then
switches the file to HDF5 SWMR (single-writer/multiple-reader) mode. Until then HDF5 marks the file
open for writing and no reader can open it, so it is set up under a hidden name
(``.<name>.partial``, :func:`~bench.record.destination.partial_path`) and moved over its final name
at :meth:`RunRecorder.start` (or at :meth:`RunRecorder.close` for a run that ends before): under its
final name a run file can always be read. That name holds, from the creation on, a placeholder: the
same skeleton, closed (status ``running``, no streams), which a writer killed during the setup leaves
behind and readers report as crashed. From then on the recorder only
resizes and writes existing chunked datasets, which HDF5 keeps consistent on disk at every flush: a
process killed with SIGKILL leaves a file that opens and holds everything up to the last flush (at
most ``flush_interval_s`` of wall time old). The final status is written after the SWMR file is
closed, because HDF5 does not support modifying attributes in SWMR mode. See ``docs/run-file.md``.

:class:`RunRecorder` holds the life cycle and the failure policy; the parts live in their own
modules: :mod:`~bench.record.destination` (file name, free space before the run, exclusive
creation), :mod:`~bench.record.skeleton` (the structure written before SWMR mode),
:mod:`~bench.record.streams` (stream datasets and row buffers), :mod:`~bench.record.events` (the
event log), :mod:`~bench.record.space` (room for the next flush, and the space reserve that lets
the file be finalised on a full disk) and :mod:`~bench.record.swmr` (finalising the status,
abandoning a failed file).

Units: run times in seconds since the start of the run (``t_s``, stream ``time``), wall times in
seconds since the Unix epoch (``wall_unix``, heartbeat), sizes in bytes.
"""

from __future__ import annotations

import math
import os
import shutil
import time
from contextlib import contextmanager
from datetime import datetime, timezone
from pathlib import Path
from types import TracebackType
from typing import Callable, Iterator, Mapping

import h5py
import numpy as np

from bench.errors import RecorderError
from bench.record import layout
from bench.record.destination import (SPACE_MARGIN_BYTES, check_destination, create_hidden, create_partial, link_new_name, partial_path,
                                      run_file_name)
from bench.record.digest import write_digest
from bench.record.events import BLOB_CHUNK_BYTES, EVENT_CHUNK_ROWS, EventLog
from bench.record.layout import EVENT_DTYPE, EVENT_KINDS, FORMAT_VERSION, MODES, STATUSES_FINAL
from bench.record.reasons import mb, os_reason
from bench.record.skeleton import write_identity, write_skeleton
from bench.record.space import RESERVE_BYTES, SpaceReserve, space_problem
from bench.record.streams import BUFFER_SPILL_BYTES, Column, StreamTable, check_name, check_stream
from bench.record.swmr import finalise_status, keep_alive

__all__ = [
    "EVENT_DTYPE", "EVENT_KINDS", "FORMAT_VERSION", "MODES", "SPACE_MARGIN_BYTES", "STATUSES_FINAL",
    "Column", "RunRecorder", "check_destination", "run_file_name",
]

FLUSH_SLACK_S = 1e-6
"""tick() tolerance (s) so that ten 0.1-s steps count as 1 s despite rounding."""
SPACE_RECHECK_S = 0.1
"""Wall time (s) one free-space reading stands for the appends after it whose need has not grown
(:meth:`RunRecorder.append`): the disk is asked again when a new chunk would be needed, after every
flush, when :attr:`RunRecorder.free_bytes` is replaced, and at least this often. An 8-h dry-run
appends 14,400 monitor rows an hour of run time; asking the file system at each was 8 % of it."""
FINALISE_MIN_BYTES = 64 * 1024
"""Free space (bytes) below which the final status is not written: reopening the file read-write
and failing to close it would leave a file HDF5 refuses to open; without it the file stays as
closed from SWMR mode, readable with every row written (reported as crashed)."""


class RunRecorder:
    """Writes one run to one HDF5 file; see the module docstring and ``docs/run-file.md``.

    Life cycle: :meth:`create` → :meth:`add_instrument` / :meth:`add_stream` → :meth:`start` →
    :meth:`append` / :meth:`event` / :meth:`tick` … → :meth:`close`. Data passed to ``append`` and
    ``event`` is buffered in memory and written at the next flush; :meth:`tick` flushes once
    ``flush_interval_s`` of wall time has passed since the last flush.
    """

    path: Path

    def __init__(self, path: Path, file: h5py.File, flush_interval_s: float, wall_clock: Callable[[], float],
                 reserve: SpaceReserve | None = None, writing: Path | None = None):
        """Use :meth:`create`."""
        self.path = path
        self._writing = writing if writing is not None else path  # where the file is until it is published at self.path
        self._reserve = reserve
        self.flush_interval_s = float(flush_interval_s)
        self._f: h5py.File | None = file
        self._wall_clock = wall_clock
        self._streams: dict[str, StreamTable] = {}
        self._events = EventLog(file)
        self._heartbeat_ds: h5py.Dataset = file[layout.HEARTBEAT]
        self._started = False
        self._state = "open"  # open | released (SWMR file closed, status not final) | closed
        self._failure = ""  # reason of the first failed or refused write; no writes after it
        self._broken = False  # an HDF5 write failed: handles abandoned, status cannot be finalised
        self._free_bytes: Callable[[Path], int] = lambda d: shutil.disk_usage(d).free
        self._space_checked_at = -math.inf  # wall time of the last free-space check that passed
        self._checked_parts: dict[str, int] = {}  # stream key (and "" for the events) -> its bytes needed at that check
        self._run_time_s = 0.0
        self._last_flush = wall_clock()

    @property
    def free_bytes(self) -> Callable[[Path], int]:
        """Free space (bytes) of a directory; a seam for fault injection (``disk_full``): setting it
        makes the next append ask again."""
        return self._free_bytes

    @free_bytes.setter
    def free_bytes(self, fn: Callable[[Path], int]) -> None:
        self._free_bytes = fn
        self._forget_space_check()

    # ---- creation -------------------------------------------------------------------------
    @classmethod
    def create(
        cls,
        runs_dir: Path,
        *,
        procedure_name: str,
        procedure_text: str,
        procedure_path: str,
        config_text: str,
        config_path: str,
        mode: str,
        operator: str | None = None,
        software_version: str,
        started_utc: datetime | None = None,
        flush_interval_s: float = 1.0,
        wall_clock: Callable[[], float] = time.monotonic,
        identity: Mapping[str, str] | None = None,
    ) -> "RunRecorder":
        """Create ``runs_dir/<run_file_name>`` (``_1``, ``_2`` … on collision; never overwrites).

        ``operator`` defaults to the login name; ``started_utc`` to now. ``flush_interval_s`` is
        wall time (s) between flushes triggered by :meth:`tick`, measured with ``wall_clock``
        (seconds, monotonic). ``identity``: root attributes naming the unit under test and the
        station, and where the operator's name came from (keys of :data:`~bench.record.layout.CREATION_ATTRS`; only
        those given are written).
        Raises :class:`DestinationError` if the directory cannot take the file,
        :class:`RecorderError` if writing it fails, ``ValueError`` for a bad ``mode`` or identity key.
        """
        if mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
        unknown = sorted(set(identity or {}) - set(layout.CREATION_ATTRS))
        if unknown:
            raise ValueError(f"identity keys must be among {', '.join(layout.CREATION_ATTRS)}, got {', '.join(unknown)}")
        if not flush_interval_s > 0:
            raise ValueError(f"flush_interval_s must be > 0 s, got {flush_interval_s!r}")
        started = layout.as_utc(started_utc or datetime.now(timezone.utc))
        runs_dir = Path(runs_dir)
        placeholder, hidden = create_hidden(runs_dir, run_file_name(started, procedure_name))
        reserve: SpaceReserve | None = None
        f: h5py.File | None = None
        path = hidden
        made = [hidden]
        try:
            skeleton = dict(procedure_name=procedure_name, procedure_text=procedure_text, procedure_path=procedure_path,
                            config_text=config_text, config_path=config_path, mode=mode, operator=operator,
                            software_version=software_version, started=started, identity=identity)
            write_skeleton(placeholder, **skeleton)
            write_digest(placeholder)
            placeholder.close()
            path = link_new_name(runs_dir, started, procedure_name, hidden)  # the name, taken exclusively, readable at once
            made = [hidden, path, partial_path(path)]
            if hidden.exists():  # (a file system without hard links renamed it)
                os.unlink(hidden)
            try:
                reserve = SpaceReserve.create(path, RESERVE_BYTES)
            except OSError as exc:
                raise RecorderError(f"writing {path} failed: disk nearly full: no room for the {mb(RESERVE_BYTES)} "
                                    f"kept to finalise the file ({os_reason(exc)})") from None
            f = create_partial(path)
            write_skeleton(f, **skeleton)
        except BaseException as exc:  # also KeyboardInterrupt: a half-made file holds nothing recorded
            _discard_new_file([placeholder, f], made, reserve)
            if isinstance(exc, RecorderError) or not isinstance(exc, Exception):
                raise
            raise RecorderError(f"writing {path} failed: {os_reason(exc)}") from None
        return cls(path, f, flush_interval_s, wall_clock, reserve, writing=partial_path(path))

    def add_instrument(self, name: str, info: dict[str, str]) -> None:
        """Record an instrument's identity (vendor, model, serial, firmware, transport, port …)
        as attributes of ``/instruments/<name>``. Only before :meth:`start`."""
        self._require_setup("add_instrument")
        check_name(name, "instrument name")
        f = self._file()
        if name in f[layout.INSTRUMENTS]:
            raise ValueError(f"instrument {name!r} was already added")
        with self._io():
            write_identity(f, name, info)

    def add_stream(self, instrument: str, columns: list[Column], stream: str = "", *, rate_hz: float | None = None) -> str:
        """Declare a stream: ``/streams/<instrument>[/<stream>]`` with a ``time`` dataset (float64,
        run time in s) and one dataset per column (attribute ``units``), all resizable along rows.

        Chunks hold ~2 s of data when the nominal ``rate_hz`` (Hz) is given, else 4096 rows, at most
        1 MiB; no compression. Returns the stream key (``instrument`` or ``instrument/stream``).
        Only before :meth:`start`.
        """
        self._require_setup("add_stream")
        f = self._file()
        key, dtypes = check_stream(f, self._streams, instrument, columns, stream)
        with self._io():
            self._streams[key] = StreamTable.create(f, key, columns, dtypes, rate_hz)
        return key

    def start(self) -> None:
        """Switch the file to SWMR mode and flush: from here on a killed process leaves a
        readable file. Events logged and rows appended before are written now."""
        self._require_setup("start")
        f = self._file()
        self._hold_reserve()
        with self._io():
            write_digest(f)  # attributes cannot change in SWMR mode: this one holds until the file is finalised
            f.flush()
            f.swmr_mode = True
        self._started = True
        self.flush()
        self._publish()

    # ---- recording ------------------------------------------------------------------------
    def append(self, stream_key: str, time_s: np.ndarray, **columns: np.ndarray) -> None:
        """Append a batch of rows to a stream: ``time_s`` (n,) run times in s, and every column of
        the stream as an array of shape (n, *column.shape). Rows are written at the next flush.

        Raises ``ValueError`` for an unknown stream, missing/extra columns, wrong shapes or a dtype
        that cannot be stored without loss (float into an integer column, integers out of range).
        """
        self._require_open()
        st = self._stream(stream_key)
        batch = st.prepare(time_s, columns)
        n = batch[layout.TIME].shape[0]
        if n == 0:
            return
        st.push(batch)
        self._accept(st, n, float(batch[layout.TIME][-1]), lambda: st.pop(batch))

    def append_row(self, stream_key: str, t_s: float, values: Mapping[str, float]) -> None:
        """Append one row: run time ``t_s`` (s) and a number for every column (a polled
        instrument's reading). Same checks and guarantees as :meth:`append` with one-row arrays,
        without making them: a stream of scalar float columns buffers the numbers and makes the
        arrays at the next flush (others go through :meth:`append`)."""
        self._require_open()
        st = self._stream(stream_key)
        if not st.takes_rows:
            self.append(stream_key, np.array([t_s]), **{k: np.array([v]) for k, v in values.items()})
            return
        st.push_row(t_s, values)
        self._accept(st, 1, float(t_s), st.pop_row)

    def _accept(self, st: StreamTable, n: int, t_last_s: float, undo: Callable[[], None]) -> None:
        """Count ``n`` rows just buffered in ``st`` (the last at run time ``t_last_s``, s) if they and
        the reserve fit (else ``undo()`` and :class:`RecorderError`: nothing accepted is lost); write
        the stream's buffer once it is large. The disk is asked again only when the need grew or the
        last reading is :data:`SPACE_RECHECK_S` old. The need of every stream and of the events can
        only have grown past what the last check covered through an append (which asks) or an event,
        so comparing this stream's and the events' needs with that check's tells whether the total
        grew, without summing over every stream at every append."""
        if self._started:
            parts = self._checked_parts
            if (st.need_bytes() > parts.get(st.key, -1) or self._events.need_bytes() > parts.get("", -1)
                    or self._wall_clock() - self._space_checked_at >= SPACE_RECHECK_S):
                try:
                    self._check_space()
                except RecorderError:
                    undo()
                    raise
        st.appended += n
        self._note_run_time(t_last_s)
        if st.pending_bytes >= BUFFER_SPILL_BYTES:
            self._check_space()
            with self._io():
                st.write()

    def event(self, kind: str, source: str = "", message: str = "", *, t_s: float, step: int = layout.NO_STEP,
              data: bytes = b"") -> None:
        """Log an event at run time ``t_s`` (s). ``kind`` is 1-16 ASCII characters (see
        ``EVENT_KINDS``); ``source`` is cut to 32 utf-8 bytes; ``step`` is the 0-based step index
        or -1; ``message`` (utf-8) and ``data`` (raw bytes) are stored whole in ``/events_blob``.
        Written at the next flush (events before :meth:`start` at start). After a refused flush
        (disk nearly full) events are still accepted and written by :meth:`close`, so the file
        tells how the run ended; after a failed HDF5 write this raises :class:`RecorderError`."""
        if self._state != "open":
            raise ValueError(f"recorder for {self.path} is closed")
        if self._broken:
            raise RecorderError(f"writing {self.path} failed earlier: {self._failure}")
        self._events.add(kind, source, message, t_s=t_s, step=step, data=data)
        self._note_run_time(t_s)

    def tick(self, run_time_s: float | None = None) -> None:
        """Note the current run time (s) and flush if ``flush_interval_s`` of wall time has passed
        since the last flush. Cheap: call it often. Does nothing before :meth:`start`."""
        if run_time_s is not None:
            self._note_run_time(run_time_s)
        if self._started and self._state == "open" and self._wall_clock() - self._last_flush >= self.flush_interval_s - FLUSH_SLACK_S:
            self.flush()

    def flush(self) -> None:
        """Write every buffered row and event, update ``/heartbeat`` and flush the file to the OS.

        Raises :class:`RecorderError` ("writing <path> failed: <reason>") if anything fails, and
        before writing if the free space or the file-size limit might not take the flush; after a
        failure the recorder refuses further writes.
        """
        self._require_open()
        self._file()
        self._check_space()
        with self._io():
            for st in self._streams.values():
                st.write()
            self._write_events_and_heartbeat()
        self._last_flush = self._wall_clock()
        self._forget_space_check()  # the flush took some of the space read

    def rows_written(self, stream_key: str) -> int:
        """Rows appended to ``stream_key`` so far (accepted by :meth:`append`, flushed or not)."""
        return self._stream(stream_key).appended

    def rows_on_disk(self, stream_key: str) -> int:
        """Rows of ``stream_key`` written to the file's datasets (flushed to the OS at the last flush)."""
        return self._stream(stream_key).on_disk

    @property
    def stream_keys(self) -> list[str]:
        """Keys of the declared streams, in declaration order."""
        return list(self._streams)

    @property
    def started(self) -> bool:
        """True once :meth:`start` switched the file to SWMR mode."""
        return self._started

    @property
    def closed(self) -> bool:
        """True once :meth:`close` finalised the file."""
        return self._state == "closed"

    def space_needed(self) -> int:
        """Bytes the next flush may allocate plus the reserve kept for finalising (bytes)."""
        return RESERVE_BYTES + self._events.need_bytes() + self._rows_need()

    def reserve_bytes(self) -> int:
        """Size (bytes) of the space reserve held for closing the file: :data:`RESERVE_BYTES` plus a
        chunk of every dataset (what the last rows and events of one flush interval allocate)."""
        events = EVENT_CHUNK_ROWS * layout.EVENT_DTYPE.itemsize + BLOB_CHUNK_BYTES
        return RESERVE_BYTES + events + sum(sum(st.chunk_bytes.values()) for st in self._streams.values())

    # ---- closing --------------------------------------------------------------------------
    def close(self, status: str, abort_reason: str = "") -> None:
        """Flush, close the SWMR file, reopen it (non-SWMR) and write the final root attributes
        ``status`` (completed | aborted | failed), ``ended_utc``, ``abort_reason`` and row totals.

        Idempotent once it succeeded. Raises :class:`RecorderError` if writing fails. After a
        refused flush (disk nearly full, file-size limit) the file is still finalised, as
        ``aborted`` if ``completed`` was asked; after a failed HDF5 write it cannot be (it keeps the
        data of the last successful flush and reads as crashed), and every call raises.

        The space reserve is deleted first, so these writes have its room even on a disk another
        process filled. If less than :data:`FINALISE_MIN_BYTES` is free all the same, the status
        is not written (raises; the file reads as crashed with every row written, and a later
        call may still finalise it).
        """
        if status not in STATUSES_FINAL:
            raise ValueError(f"status must be one of {', '.join(STATUSES_FINAL)}, got {status!r}")
        if self._state == "closed":
            return
        flush_error: RecorderError | None = None
        if self._reserve is not None:
            self._reserve.release()  # its blocks are the room of the writes below, even on a full disk
        if self._state == "open":
            flush_error = self._last_flush_before_close()
            self._release()
        if self._broken:
            raise RecorderError(
                f"writing {self.path} failed: {self._failure}; the file keeps everything up to the last successful "
                "flush, but its status cannot be finalised (it reads as crashed)"
            )
        downgraded = bool(self._failure) and status == layout.STATUS_COMPLETED
        if downgraded:
            status = layout.STATUS_ABORTED
        if self._failure and not abort_reason:
            abort_reason = f"writing the run file failed: {self._failure}"
        self._check_room_to_finalise(status)
        try:
            finalise_status(self._writing, self._streams.values(), status, abort_reason)
        except Exception as exc:  # noqa: BLE001 - h5py raises several types
            raise RecorderError(f"writing {self.path} failed: finalising status {status!r}: {os_reason(exc)}") from None
        self._publish()  # a run that ended before start(): its file, finalised, replaces the placeholder
        self._state = "closed"
        if flush_error is not None or downgraded:
            raise RecorderError(f"writing {self.path} failed: {self._failure}; the file was closed with status {status!r}")

    def __enter__(self) -> "RunRecorder":
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        """Close on leaving the block: ``aborted`` with the exception text, else ``completed``."""
        if self._state == "closed":
            return
        if exc is not None:
            self.close(layout.STATUS_ABORTED, str(exc) or type(exc).__name__)
        else:
            self.close(layout.STATUS_COMPLETED)

    # ---- internals ------------------------------------------------------------------------
    def _publish(self) -> None:
        """Move the file set up under its hidden name over the placeholder at :attr:`path` (atomic:
        a reader opens either the placeholder or the whole file). :class:`RecorderError` if it fails."""
        if self._writing == self.path:
            return
        try:
            os.replace(self._writing, self.path)
        except OSError as exc:
            self._failure = self._failure or f"moving {self._writing.name} to its name: {os_reason(exc)}"
            raise RecorderError(f"writing {self.path} failed: {self._failure}") from None
        self._writing = self.path

    def _file(self) -> h5py.File:
        if self._f is None:
            raise ValueError(f"recorder for {self.path} is closed")
        return self._f

    def _stream(self, key: str) -> StreamTable:
        st = self._streams.get(key)
        if st is None:
            raise ValueError(f"unknown stream {key!r} (streams: {', '.join(self._streams) or 'none'})")
        return st

    def _require_open(self) -> None:
        if self._state != "open":
            raise ValueError(f"recorder for {self.path} is closed")
        if self._failure:
            raise RecorderError(f"writing {self.path} failed earlier: {self._failure}")

    def _require_setup(self, what: str) -> None:
        self._require_open()
        if self._started:
            raise ValueError(f"{what}() is only allowed before start(): the file is in SWMR mode, where HDF5 cannot add objects")

    def _note_run_time(self, t_s: float) -> None:
        """The run has got at least to ``t_s`` (s); written to the heartbeat at the next flush."""
        if t_s > self._run_time_s and t_s != math.inf:  # NaN compares false
            self._run_time_s = float(t_s)

    @contextmanager
    def _io(self) -> Iterator[None]:
        """Turn any failure of h5py/HDF5 into RecorderError, remember it and abandon the handles."""
        try:
            yield
        except RecorderError:
            raise
        except Exception as exc:  # noqa: BLE001 - h5py raises OSError, RuntimeError, KeyError, ValueError...
            self._fail(exc)
            self._abandon()
            raise RecorderError(f"writing {self.path} failed: {self._failure}") from None

    def _fail(self, exc: BaseException) -> None:
        if not self._failure:
            self._failure = os_reason(exc)

    def _abandon(self) -> None:
        """Keep every HDF5 handle of the failed file alive until the process ends (see
        :func:`bench.record.swmr.keep_alive`) and refuse further writes."""
        objs: list[object] = [self._f, self._heartbeat_ds, *self._events.handles()]
        for st in self._streams.values():
            objs.extend(st.handles())
        keep_alive(objs)
        self._broken = True
        self._f = None
        if self._reserve is not None:
            self._reserve.release()  # the file cannot be finalised: give the room back

    def _last_flush_before_close(self) -> RecorderError | None:
        """The flush of :meth:`close`: everything, or after a refused flush what still fits; the
        error it raised, if any."""
        try:
            if not self._failure:
                self.flush()
            elif not self._broken:
                self._flush_events_only()
        except RecorderError as exc:
            return exc
        return None

    def _release(self) -> None:
        """Close the SWMR file (unless HDF5 failed, see :meth:`_abandon`): state ``released``."""
        if not self._broken:
            f, self._f = self._f, None
            try:
                if f is not None:
                    f.close()
            except Exception as exc:  # noqa: BLE001
                self._fail(exc)
                self._broken = True
        self._state = "released"

    def _flush_events_only(self) -> None:
        """After a refused flush: write the rows accepted before the refusal when they fit in the
        space the refusal kept in reserve (a flush is refused while less than RESERVE_BYTES would
        remain, so they normally do: nothing accepted is lost), then the buffered events (small:
        the abort story) if they fit."""
        rows_need = self._rows_need()
        if any(st.pending_rows for st in self._streams.values()) and not self._space_problem(
                RESERVE_BYTES // 4 + rows_need + self._events.need_bytes()):
            with self._io():
                for st in self._streams.values():
                    st.write()
        for st in self._streams.values():
            st.discard()
        problem = self._space_problem(RESERVE_BYTES // 4 + self._events.need_bytes())
        if problem:
            raise RecorderError(f"writing {self.path} failed: {problem}; the last events were not written")
        with self._io():
            self._write_events_and_heartbeat()

    def _write_events_and_heartbeat(self) -> None:
        """Write the buffered events, the heartbeat [wall time s since epoch, run time s], and flush
        HDF5's caches to the OS. Call inside :meth:`_io`."""
        self._events.write()
        self._heartbeat_ds[...] = np.array([time.time(), self._run_time_s])
        self._file().flush()

    def _rows_need(self) -> int:
        """Bytes of new chunks writing the buffered stream rows allocates."""
        return sum(st.need_bytes() for st in self._streams.values())

    def _space_problem(self, need: int) -> str:
        """Why ``need`` more bytes might not fit in the file (free space, ``ulimit -f``), or ""."""
        return space_problem(self._writing, need, self.free_bytes)

    def _hold_reserve(self) -> None:
        """Grow the space reserve to :meth:`reserve_bytes` now that the streams are known; a disk
        that cannot give it refuses the start like a refused flush."""
        if self._reserve is None:
            return
        try:
            self._reserve.ensure(self.reserve_bytes())
        except OSError as exc:
            self._failure = (f"disk nearly full: no room for the {mb(self.reserve_bytes())} kept to finalise the file "
                             f"({os_reason(exc)}); recording stopped while the file is still consistent")
            raise RecorderError(f"writing {self.path} failed: {self._failure}") from None

    def _check_room_to_finalise(self, status: str) -> None:
        """Refuse to reopen the file for its final status when the disk has less than
        :data:`FINALISE_MIN_BYTES` free (the reserve was taken by another process): failing to
        close it then would leave a file HDF5 refuses to open."""
        try:
            free = self.free_bytes(self.path.parent)
        except OSError:
            return
        if free < FINALISE_MIN_BYTES:
            raise RecorderError(
                f"writing {self.path} failed: disk full ({mb(free)} free): status {status!r} not written; the file keeps "
                "every row written and reads as crashed"
            )

    def _forget_space_check(self) -> None:
        """The next append asks the disk again."""
        self._space_checked_at = -math.inf
        self._checked_parts = {}

    def _check_space(self) -> None:
        """Refuse a flush that might not fit on the disk or under the file-size limit (``ulimit -f``).

        HDF5 does not recover from a failed write (see :meth:`_abandon`); stopping just before
        keeps the file consistent and closable with status ``aborted``. The estimate is the size
        of the chunks the flush allocates (HDF5 allocates whole chunks) plus 1 MiB for metadata
        and finalising.
        """
        need = self.space_needed()
        problem = self._space_problem(need)
        if not problem:
            self._space_checked_at = self._wall_clock()
            self._checked_parts = {key: st.need_bytes() for key, st in self._streams.items()}
            self._checked_parts[""] = self._events.need_bytes()
        else:
            self._failure = f"{problem}; recording stopped while the file is still consistent"
            raise RecorderError(f"writing {self.path} failed: {self._failure}")


def _discard_new_file(files: list[h5py.File | None], paths: list[Path], reserve: SpaceReserve | None) -> None:
    """Close and delete a run file whose creation failed or was interrupted (it holds nothing
    recorded): its placeholder and its partial file, and its reserve."""
    for f in files:
        try:
            if f is not None:
                f.close()
        except Exception:  # noqa: BLE001 - already reporting the first failure
            pass
    for path in paths:
        try:
            os.unlink(path)
        except OSError:
            pass
    if reserve is not None:
        reserve.release()
