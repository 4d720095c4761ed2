"""Crash-safe HDF5 run recorder: one file per run, written in SWMR mode.

The whole file layout (root attributes, texts, instrument groups, stream datasets, events table,
heartbeat) is created first; :meth:`RunRecorder.start` then switches the file to HDF5 SWMR
(single-writer/multiple-reader) mode. From then on the recorder only resizes and writes existing
chunked datasets, which HDF5 keeps consistent on disk at every flush: a process killed with SIGKILL
leaves a file that opens and holds everything up to the last flush (at most ``flush_interval_s``
of wall time old). The final status is written after the SWMR file is closed, because HDF5 does
not support modifying attributes in SWMR mode. See ``docs/run-file.md`` for the layout.

Units: run times in seconds since the start of the run (``t_s``, stream ``time``), wall times in
seconds since the Unix epoch (``wall_unix``, heartbeat), sizes in bytes.
"""

from __future__ import annotations

import ctypes
import getpass
import os
import re
import shutil
import socket
import tempfile
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from types import TracebackType
from typing import Callable, Iterator

import h5py
import numpy as np

from bench.errors import DestinationError, RecorderError

try:
    import resource
except ImportError:  # not on Windows
    resource = None  # type: ignore[assignment]

FORMAT_VERSION = 1
"""Version of the run-file layout. Readers refuse files with a higher version."""

SPACE_MARGIN_BYTES = 50 * 1024 * 1024
"""Free space (bytes) required on top of the estimated run-file size."""

MODES = ("sim", "hardware", "replay", "imported")
STATUSES_FINAL = ("completed", "aborted", "failed")

EVENT_DTYPE = np.dtype(
    [
        ("t_s", "<f8"),
        ("wall_unix", "<f8"),
        ("kind", "S16"),
        ("source", "S32"),
        ("step", "<i4"),
        ("msg_off", "<u8"),
        ("msg_len", "<u4"),
        ("data_off", "<u8"),
        ("data_len", "<u4"),
    ]
)
"""Row of the ``/events`` table. Texts are utf-8; messages and data bytes live in ``/events_blob``."""

EVENT_KINDS = (
    "run_start", "step_start", "step_end", "command", "reply", "stream",
    "error", "fault", "abort", "note", "safe_state", "run_end",
)
"""Event kinds written by the runner (others up to 16 ASCII bytes are accepted)."""

EVENT_CHUNK_ROWS = 1024
BLOB_CHUNK_BYTES = 64 * 1024
DEFAULT_CHUNK_ROWS = 4096
MAX_CHUNK_BYTES = 1024 * 1024  # stays inside HDF5's default 1 MiB chunk cache per dataset
MIN_CHUNK_ROWS = 64
BUFFER_SPILL_BYTES = 16 * 1024 * 1024  # a stream's buffer is written out early past this size (bytes)
FLUSH_SLACK_S = 1e-6  # tick() tolerance (s) so that ten 0.1-s steps count as 1 s despite rounding
RESERVE_BYTES = 1024 * 1024  # kept free for metadata and finalising the status (bytes)

_NAME_BAD = re.compile(r"[^A-Za-z0-9._-]+")
_HDF5_REASON = re.compile(r"error message = '([^']*)'")


@dataclass
class Column:
    """One recorded quantity of a stream.

    ``units`` is a unit string (pint syntax, "1" for dimensionless); ``dtype`` a numpy dtype string
    (numeric or bool); ``shape`` the shape of one row, ``()`` for a scalar, ``(3,)`` for a 3-axis vector.
    """

    name: str
    units: str
    dtype: str = "f8"
    shape: tuple[int, ...] = ()


@dataclass
class _Stream:
    key: str
    group: h5py.Group
    columns: list[Column]
    dtypes: dict[str, np.dtype]
    datasets: dict[str, h5py.Dataset]  # "time" and every column
    pending: dict[str, list[np.ndarray]]
    pending_rows: int = 0
    pending_bytes: int = 0
    row_bytes: int = 0
    chunk_rows: dict[str, int] = field(default_factory=dict)  # per dataset
    chunk_bytes: dict[str, int] = field(default_factory=dict)
    on_disk: int = 0  # rows written to the datasets
    appended: int = 0  # rows accepted by append()


def check_destination(runs_dir: Path, estimated_bytes: int) -> None:
    """Refuse a run before it starts if ``runs_dir`` cannot take its file.

    Creates ``runs_dir`` if needed, proves it writable by creating and deleting a temporary file,
    and requires ``estimated_bytes`` + 50 MB of free space (bytes, from ``shutil.disk_usage``).
    Raises :class:`DestinationError` naming the problem and the directory.
    """
    runs_dir = Path(runs_dir)
    try:
        runs_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DestinationError(f"runs directory {runs_dir} cannot be created: {_os_reason(exc)}") from None
    if not runs_dir.is_dir():
        raise DestinationError(f"runs directory {runs_dir} is not a directory")
    try:
        fd, probe = tempfile.mkstemp(prefix=".bench-write-test-", dir=runs_dir)
        try:
            os.write(fd, b"bench")
        finally:
            os.close(fd)
            os.unlink(probe)
    except OSError as exc:
        raise DestinationError(f"runs directory {runs_dir} is not writable: {_os_reason(exc)}") from None
    try:
        free = shutil.disk_usage(runs_dir).free
    except OSError as exc:
        raise DestinationError(f"free space of runs directory {runs_dir} cannot be determined: {_os_reason(exc)}") from None
    need = max(int(estimated_bytes), 0) + SPACE_MARGIN_BYTES
    if free < need:
        raise DestinationError(
            f"not enough free space in runs directory {runs_dir}: {_mb(free)} free, the run needs "
            f"{_mb(need)} (estimated run file {_mb(max(int(estimated_bytes), 0))} + {_mb(SPACE_MARGIN_BYTES)} margin)"
        )


def run_file_name(started_utc: datetime, procedure_name: str) -> str:
    """File name of a run: ``<YYYYMMDDTHHMMSSZ>_<procedure>.h5`` with the start time in UTC.

    The procedure name is reduced to ``[A-Za-z0-9._-]`` (other runs of characters become ``_``,
    at most 80 characters, ``run`` if nothing is left). A naive datetime is taken as UTC.
    """
    stamp = _as_utc(started_utc).strftime("%Y%m%dT%H%M%SZ")
    name = _NAME_BAD.sub("_", procedure_name).strip("._-")[:80].rstrip("._-") or "run"
    return f"{stamp}_{name}.h5"


class RunRecorder:
    """Writes one run to one HDF5 file; see the module docstring and ``docs/run-file.md``.

    Life cycle: :meth:`create` → :meth:`add_instrument` / :meth:`add_stream` → :meth:`start` →
    :meth:`append` / :meth:`event` / :meth:`tick` … → :meth:`close`. Data passed to ``append`` and
    ``event`` is buffered in memory and written at the next flush; :meth:`tick` flushes once
    ``flush_interval_s`` of wall time has passed since the last flush.
    """

    path: Path

    def __init__(self, path: Path, file: h5py.File, flush_interval_s: float, wall_clock: Callable[[], float]):
        """Use :meth:`create`."""
        self.path = path
        self.flush_interval_s = float(flush_interval_s)
        self._f: h5py.File | None = file
        self._wall_clock = wall_clock
        self._streams: dict[str, _Stream] = {}
        self._started = False
        self._state = "open"  # open | released (SWMR file closed, status not final) | closed
        self._failure = ""  # reason of the first failed or refused write; no writes after it
        self.free_bytes: Callable[[Path], int] = lambda d: shutil.disk_usage(d).free
        """Free space (bytes) of a directory; a seam for fault injection (``disk_full``)."""
        self._broken = False  # an HDF5 write failed: handles abandoned, status cannot be finalised
        self._events: list[tuple] = []
        self._blob_pending = bytearray()
        self._blob_total = 0  # bytes in /events_blob including pending (= offset of the next message)
        self._events_on_disk = 0
        self._run_time_s = 0.0
        self._last_flush = wall_clock()
        self._events_ds: h5py.Dataset = file["events"]
        self._blob_ds: h5py.Dataset = file["events_blob"]
        self._heartbeat_ds: h5py.Dataset = file["heartbeat"]

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
    ) -> "RunRecorder":
        """Create ``runs_dir/<run_file_name>`` (``_1``, ``_2`` … on collision; never overwrites).

        ``operator`` defaults to the login name; ``started_utc`` to now. ``flush_interval_s`` is
        wall time (s) between flushes triggered by :meth:`tick`, measured with ``wall_clock``
        (seconds, monotonic). Raises :class:`DestinationError` if the directory cannot take the
        file, :class:`RecorderError` if writing it fails, ``ValueError`` for a bad ``mode``.
        """
        if mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
        if not flush_interval_s > 0:
            raise ValueError(f"flush_interval_s must be > 0 s, got {flush_interval_s!r}")
        started = _as_utc(started_utc or datetime.now(timezone.utc))
        runs_dir = Path(runs_dir)
        try:
            runs_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise DestinationError(f"runs directory {runs_dir} cannot be created: {_os_reason(exc)}") from None
        base = run_file_name(started, procedure_name)[: -len(".h5")]
        f, path = None, runs_dir / f"{base}.h5"
        for n in range(10_000):
            path = runs_dir / (f"{base}.h5" if n == 0 else f"{base}_{n}.h5")
            if path.exists():
                continue
            try:
                f = h5py.File(path, "x", libver="latest")
                break
            except FileExistsError:
                continue
            except PermissionError as exc:
                raise DestinationError(f"run file {path} cannot be created: {_os_reason(exc)}") from None
            except Exception as exc:  # noqa: BLE001 - h5py raises several types; report them all the same way
                raise RecorderError(f"writing {path} failed: {_os_reason(exc)}") from None
        if f is None:
            raise DestinationError(f"no free run-file name for {base} in {runs_dir}")
        try:
            a = f.attrs
            a["format_version"] = np.int64(FORMAT_VERSION)
            a["software_version"] = str(software_version)
            a["procedure_name"] = str(procedure_name)
            a["procedure_path"] = str(procedure_path)
            a["config_path"] = str(config_path)
            a["operator"] = operator if operator is not None else _login_name()
            a["host"] = socket.gethostname()
            a["mode"] = mode
            a["started_utc"] = _iso_z(started)
            a["ended_utc"] = ""
            a["status"] = "running"
            a["abort_reason"] = ""
            _write_text(f.create_group("procedure"), procedure_text)
            _write_text(f.create_group("config"), config_text)
            f.create_group("instruments")
            f.create_group("streams")
            ev = f.create_dataset("events", shape=(0,), maxshape=(None,), dtype=EVENT_DTYPE, chunks=(EVENT_CHUNK_ROWS,))
            ev.attrs["units"] = "t_s: s (run time); wall_unix: s (Unix time); msg_off, data_off, *_len: bytes in /events_blob"
            blob = f.create_dataset("events_blob", shape=(0,), maxshape=(None,), dtype="u1", chunks=(BLOB_CHUNK_BYTES,))
            blob.attrs["units"] = "bytes (utf-8 messages and raw event data)"
            hb = f.create_dataset("heartbeat", data=np.array([time.time(), 0.0]), dtype="f8")
            hb.attrs["units"] = "s"
            hb.attrs["fields"] = "wall_unix,run_time_s"
        except Exception as exc:  # noqa: BLE001
            _close_quietly(f)
            raise RecorderError(f"writing {path} failed: {_os_reason(exc)}") from None
        return cls(path, f, flush_interval_s, wall_clock)

    def add_instrument(self, name: str, info: dict[str, str]) -> None:
        """Record an instrument's identity (vendor, model, serial, firmware, transport, port …)
        as attributes of ``/instruments/<name>``. Only before :meth:`start`."""
        self._require_setup("add_instrument")
        _check_name(name, "instrument name")
        f = self._file()
        if name in f["instruments"]:
            raise ValueError(f"instrument {name!r} was already added")
        with self._io():
            g = f["instruments"].create_group(name, track_order=True)
            for k, v in info.items():
                g.attrs[str(k)] = str(v)

    def add_stream(self, instrument: str, columns: list[Column], stream: str = "", *, rate_hz: float | None = None) -> str:
        """Declare a stream: ``/streams/<instrument>[/<stream>]`` with a ``time`` dataset (float64,
        run time in s) and one dataset per column (attribute ``units``), all resizable along rows.

        Chunks hold ~2 s of data when the nominal ``rate_hz`` (Hz) is given, else 4096 rows, at most
        1 MiB; no compression. Returns the stream key (``instrument`` or ``instrument/stream``).
        Only before :meth:`start`.
        """
        self._require_setup("add_stream")
        _check_name(instrument, "instrument name")
        if stream:
            _check_name(stream, "stream name")
        key = f"{instrument}/{stream}" if stream else instrument
        if key in self._streams:
            raise ValueError(f"stream {key!r} was already added")
        if not columns:
            raise ValueError(f"stream {key!r} needs at least one column")
        dtypes: dict[str, np.dtype] = {}
        for c in columns:
            _check_name(c.name, f"column name of stream {key!r}")
            if c.name == "time":
                raise ValueError(f"stream {key!r}: column name 'time' is reserved for the run time of each row")
            if c.name in dtypes:
                raise ValueError(f"stream {key!r}: column {c.name!r} appears twice")
            try:
                dt = np.dtype(c.dtype)
            except TypeError as exc:
                raise ValueError(f"stream {key!r}: column {c.name!r}: bad dtype {c.dtype!r}: {exc}") from None
            if dt.kind not in "biuf":
                raise ValueError(f"stream {key!r}: column {c.name!r}: dtype {c.dtype!r} is not numeric or bool")
            if not all(isinstance(s, (int, np.integer)) and s > 0 for s in c.shape):
                raise ValueError(f"stream {key!r}: column {c.name!r}: row shape {c.shape!r} must be positive integers")
            dtypes[c.name] = dt
        f = self._file()
        parent_path = f"streams/{instrument}"
        if not stream and parent_path in f:
            raise ValueError(f"stream {key!r} cannot be added: /{parent_path} already holds other streams")
        if stream:
            for other in self._streams.values():
                if other.key == instrument:
                    raise ValueError(f"stream {key!r} cannot be added: /{parent_path} is already a stream")
        row_bytes = 8 + sum(dtypes[c.name].itemsize * int(np.prod(c.shape, dtype=np.int64)) for c in columns)
        with self._io():
            g = f.require_group(parent_path)
            if stream:
                g = g.create_group(stream)
            g.attrs["instrument"] = instrument
            g.attrs["stream"] = stream
            g.attrs["columns"] = ",".join(["time"] + [c.name for c in columns])
            if rate_hz is not None:
                g.attrs["rate_hz_nominal"] = float(rate_hz)
            datasets = {"time": self._new_column(g, Column("time", "s", "f8"), rate_hz)}
            datasets["time"].attrs["description"] = "run time of each row (s since the start of the run)"
            for c in columns:
                datasets[c.name] = self._new_column(g, c, rate_hz)
        all_dtypes = {"time": np.dtype("f8"), **dtypes}
        self._streams[key] = _Stream(
            key, g, list(columns), all_dtypes, datasets, {n: [] for n in datasets}, row_bytes=row_bytes,
            chunk_rows={n: int(ds.chunks[0]) for n, ds in datasets.items()},
            chunk_bytes={n: _chunk_bytes(ds) for n, ds in datasets.items()},
        )
        return key

    @staticmethod
    def _new_column(g: h5py.Group, c: Column, rate_hz: float | None) -> h5py.Dataset:
        shape = tuple(int(s) for s in c.shape)
        item = np.dtype(c.dtype).itemsize * int(np.prod(shape, dtype=np.int64))
        rows = DEFAULT_CHUNK_ROWS if rate_hz is None or not rate_hz > 0 else int(round(2.0 * rate_hz))
        rows = max(MIN_CHUNK_ROWS, min(rows, MAX_CHUNK_BYTES // max(item, 1)))
        ds = g.create_dataset(c.name, shape=(0, *shape), maxshape=(None, *shape), dtype=c.dtype, chunks=(rows, *shape))
        ds.attrs["units"] = c.units
        return ds

    def start(self) -> None:
        """Switch the file to SWMR mode and flush: from here on a killed process leaves a
        readable file. Events logged and rows appended before are written now."""
        self._require_setup("start")
        f = self._file()
        with self._io():
            f.flush()
            f.swmr_mode = True
        self._started = True
        self.flush()

    # ---- recording ------------------------------------------------------------------------
    def append(self, stream_key: str, time_s: np.ndarray, **columns: np.ndarray) -> None:
        """Append a batch of rows to a stream: ``time_s`` (n,) run times in s, and every column of
        the stream as an array of shape (n, *column.shape). Rows are written at the next flush.

        Raises ``ValueError`` for an unknown stream, missing/extra columns, wrong shapes or a dtype
        that cannot be stored without loss (float into an integer column, integers out of range).
        """
        self._require_open()
        st = self._streams.get(stream_key)
        if st is None:
            raise ValueError(f"unknown stream {stream_key!r} (streams: {', '.join(self._streams) or 'none'})")
        t = np.asarray(time_s)
        if t.ndim != 1:
            raise ValueError(f"stream {stream_key!r}: time_s must be one-dimensional (n,), got shape {t.shape}")
        n = t.shape[0]
        names = [c.name for c in st.columns]
        missing = [c for c in names if c not in columns]
        extra = [c for c in columns if c not in st.dtypes or c == "time"]
        if missing or extra:
            parts = []
            if missing:
                parts.append(f"missing column(s) {', '.join(missing)}")
            if extra:
                parts.append(f"unknown column(s) {', '.join(extra)}")
            raise ValueError(f"stream {stream_key!r}: {'; '.join(parts)} (columns: {', '.join(names)})")
        batch = {"time": _convert(t, np.dtype("f8"), stream_key, "time")}
        for c in st.columns:
            a = np.asarray(columns[c.name])
            want = (n, *c.shape)
            if a.shape != want:
                raise ValueError(f"stream {stream_key!r}: column {c.name!r} has shape {a.shape}, expected {want}")
            batch[c.name] = _convert(a, st.dtypes[c.name], stream_key, c.name)
        if n == 0:
            return
        for name, a in batch.items():
            st.pending[name].append(a)
        st.pending_rows += n
        st.pending_bytes += n * st.row_bytes
        if self._started:
            try:
                self._check_space()  # accept rows only while they (and the reserve) fit: nothing accepted is lost
            except RecorderError:
                for name in batch:
                    st.pending[name].pop()
                st.pending_rows -= n
                st.pending_bytes -= n * st.row_bytes
                raise
        st.appended += n
        if n and np.isfinite(batch["time"][-1]):
            self._run_time_s = max(self._run_time_s, float(batch["time"][-1]))
        if st.pending_bytes >= BUFFER_SPILL_BYTES:
            self._check_space()
            with self._io():
                self._write_stream(st)

    def event(self, kind: str, source: str = "", message: str = "", *, t_s: float, step: int = -1, data: bytes = b"") -> None:
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
        try:
            kind_b = kind.encode("ascii")
        except UnicodeEncodeError:
            raise ValueError(f"event kind {kind!r} must be ASCII") from None
        if not 0 < len(kind_b) <= 16:
            raise ValueError(f"event kind {kind!r} must be 1 to 16 characters")
        if not -(2**31) <= step < 2**31:
            raise ValueError(f"event step {step} out of range")
        msg_b = message.encode("utf-8", errors="surrogateescape")
        data_b = bytes(data)
        msg_off = self._blob_total
        data_off = msg_off + len(msg_b)
        self._blob_pending += msg_b
        self._blob_pending += data_b
        self._blob_total += len(msg_b) + len(data_b)
        self._events.append(
            (float(t_s), time.time(), kind_b, _cut_utf8(source, 32), int(step), msg_off, len(msg_b), data_off, len(data_b))
        )
        if np.isfinite(t_s):
            self._run_time_s = max(self._run_time_s, float(t_s))

    def tick(self, run_time_s: float | None = None) -> None:
        """Note the current run time (s) and flush if ``flush_interval_s`` of wall time has passed
        since the last flush. Cheap: call it often. Does nothing before :meth:`start`."""
        if run_time_s is not None and np.isfinite(run_time_s):
            self._run_time_s = max(self._run_time_s, float(run_time_s))
        if self._started and self._state == "open" and self._wall_clock() - self._last_flush >= self.flush_interval_s - FLUSH_SLACK_S:
            self.flush()

    def flush(self) -> None:
        """Write every buffered row and event, update ``/heartbeat`` and flush the file to the OS.

        Raises :class:`RecorderError` ("writing <path> failed: <reason>") if anything fails, and
        before writing if the free space or the file-size limit might not take the flush; after a
        failure the recorder refuses further writes.
        """
        self._require_open()
        f = self._file()
        self._check_space()
        with self._io():
            for st in self._streams.values():
                self._write_stream(st)
            self._write_events()
            self._heartbeat_ds[...] = np.array([time.time(), self._run_time_s])
            f.flush()
        self._last_flush = self._wall_clock()

    def rows_written(self, stream_key: str) -> int:
        """Rows appended to ``stream_key`` so far (accepted by :meth:`append`, flushed or not)."""
        st = self._streams.get(stream_key)
        if st is None:
            raise ValueError(f"unknown stream {stream_key!r} (streams: {', '.join(self._streams) or 'none'})")
        return st.appended

    def rows_on_disk(self, stream_key: str) -> int:
        """Rows of ``stream_key`` written to the file's datasets (flushed to the OS at the last flush)."""
        st = self._streams.get(stream_key)
        if st is None:
            raise ValueError(f"unknown stream {stream_key!r} (streams: {', '.join(self._streams) or 'none'})")
        return st.on_disk

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

    # ---- closing --------------------------------------------------------------------------
    def close(self, status: str, abort_reason: str = "") -> None:
        """Flush, close the SWMR file, reopen it (non-SWMR) and write the final root attributes
        ``status`` (completed | aborted | failed), ``ended_utc``, ``abort_reason`` and row totals.

        Idempotent once it succeeded. Raises :class:`RecorderError` if writing fails. After a
        refused flush (disk nearly full, file-size limit) the file is still finalised, as
        ``aborted`` if ``completed`` was asked; after a failed HDF5 write it cannot be (it keeps the
        data of the last successful flush and reads as crashed), and every call raises.
        """
        if status not in STATUSES_FINAL:
            raise ValueError(f"status must be one of {', '.join(STATUSES_FINAL)}, got {status!r}")
        if self._state == "closed":
            return
        flush_error: RecorderError | None = None
        if self._state == "open":
            try:
                if not self._failure:
                    self.flush()
                elif not self._broken:
                    self._flush_events_only()
            except RecorderError as exc:
                flush_error = exc
            if not self._broken:
                f, self._f = self._f, None
                try:
                    if f is not None:
                        f.close()
                except Exception as exc:  # noqa: BLE001
                    self._fail(exc)
                    self._broken = True
            self._state = "released"
        if self._broken:
            raise RecorderError(
                f"writing {self.path} failed: {self._failure}; the file keeps everything up to the last successful "
                "flush, but its status cannot be finalised (it reads as crashed)"
            )
        downgraded = bool(self._failure) and status == "completed"
        if downgraded:
            status = "aborted"
        if self._failure and not abort_reason:
            abort_reason = f"writing the run file failed: {self._failure}"
        try:
            with _open_for_status(self.path) as f:
                total = 0
                for st in self._streams.values():
                    g = f["streams"][st.key]
                    rows = min(int(g[name].shape[0]) for name in st.datasets)
                    g.attrs["rows"] = np.int64(rows)
                    g.attrs["rows_appended"] = np.int64(st.appended)
                    total += rows
                f.attrs["rows_total"] = np.int64(total)
                f.attrs["ended_utc"] = _iso_z(datetime.now(timezone.utc))
                f.attrs["abort_reason"] = str(abort_reason)
                f.attrs["status"] = status
        except Exception as exc:  # noqa: BLE001 - h5py raises several types
            raise RecorderError(f"writing {self.path} failed: finalising status {status!r}: {_os_reason(exc)}") from None
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
            self.close("aborted", str(exc) or type(exc).__name__)
        else:
            self.close("completed")

    # ---- internals ------------------------------------------------------------------------
    def _file(self) -> h5py.File:
        if self._f is None:
            raise ValueError(f"recorder for {self.path} is closed")
        return self._f

    def _require_open(self) -> None:
        if self._state != "open":
            raise ValueError(f"recorder for {self.path} is closed")
        if self._failure:
            raise RecorderError(f"writing {self.path} failed earlier: {self._failure}")

    def _require_setup(self, what: str) -> None:
        self._require_open()
        if self._started:
            raise ValueError(f"{what}() is only allowed before start(): the file is in SWMR mode, where HDF5 cannot add objects")

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
            self._failure = _os_reason(exc)

    def _abandon(self) -> None:
        """Keep every HDF5 handle of a file whose write failed alive until the process ends.

        After a failed write HDF5 2.0 (h5py 3.16) crashes the process with a segmentation fault
        (use after free in ``H5D__flush_all_cb``) when the file is closed, or when its objects are
        garbage-collected, at the latest at interpreter exit. Holding one extra reference on each
        object means they are never closed: the OS closes the descriptor at exit, and the file keeps
        what the last successful flush wrote (readable as SWMR, reported as crashed).
        """
        objs: list[object] = [self._f, self._events_ds, self._blob_ds, self._heartbeat_ds]
        for st in self._streams.values():
            objs.append(st.group)
            objs.extend(st.datasets.values())
        for obj in objs:
            if obj is not None:
                ctypes.pythonapi.Py_IncRef(ctypes.py_object(obj))
        self._broken = True
        self._f = None

    def _flush_events_only(self) -> None:
        """After a refused flush: write the rows accepted before the refusal when they fit in the
        space the refusal kept in reserve (a flush is refused while less than RESERVE_BYTES would
        remain, so they normally do: nothing accepted is lost), then the buffered events (small:
        the abort story) if they fit."""
        rows_need = self._rows_need()
        if any(st.pending_rows for st in self._streams.values()) and not self._space_problem(RESERVE_BYTES // 4 + rows_need + self._events_need()):
            with self._io():
                for st in self._streams.values():
                    self._write_stream(st)
        for st in self._streams.values():
            for parts in st.pending.values():
                parts.clear()
            st.pending_rows = st.pending_bytes = 0
        need = RESERVE_BYTES // 4 + self._events_need()
        problem = self._space_problem(need)
        if problem:
            raise RecorderError(f"writing {self.path} failed: {problem}; the last events were not written")
        with self._io():
            self._write_events()
            self._heartbeat_ds[...] = np.array([time.time(), self._run_time_s])
            self._file().flush()

    def _rows_need(self) -> int:
        """Bytes of new chunks writing the buffered stream rows allocates."""
        need = 0
        for st in self._streams.values():
            if st.pending_rows:
                for name in st.datasets:
                    need += _new_chunks(st.chunk_rows[name], st.on_disk, st.pending_rows) * st.chunk_bytes[name]
        return need

    def _events_need(self) -> int:
        """Bytes of new chunks writing the buffered events allocates."""
        need = _new_chunks(EVENT_CHUNK_ROWS, self._events_on_disk, len(self._events)) * EVENT_CHUNK_ROWS * EVENT_DTYPE.itemsize
        blob_on_disk = self._blob_total - len(self._blob_pending)
        return need + _new_chunks(BLOB_CHUNK_BYTES, blob_on_disk, len(self._blob_pending)) * BLOB_CHUNK_BYTES

    def _space_problem(self, need: int) -> str:
        """Why ``need`` more bytes might not fit in the file (free space, ``ulimit -f``), or ""."""
        try:
            free = self.free_bytes(self.path.parent)
        except OSError:
            free = None
        if free is not None and free < need:
            return f"disk nearly full: {_mb(free)} free in {self.path.parent}, the next flush may need up to {_mb(need)}"
        if resource is not None:
            soft = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
            if soft != resource.RLIM_INFINITY:
                try:
                    size = os.path.getsize(self.path)
                except OSError:
                    size = 0
                if size + need > soft:
                    return (
                        f"file size limit (ulimit -f) of {_mb(soft)} reached: the file has {_mb(size)}, "
                        f"the next flush may need up to {_mb(need)}"
                    )
        return ""

    def space_needed(self) -> int:
        """Bytes the next flush may allocate plus the reserve kept for finalising (bytes)."""
        return RESERVE_BYTES + self._events_need() + self._rows_need()

    def _check_space(self) -> None:
        """Refuse a flush that might not fit on the disk or under the file-size limit (``ulimit -f``).

        HDF5 does not recover from a failed write (see :meth:`_abandon`); stopping just before
        keeps the file consistent and closable with status ``aborted``. The estimate is the size
        of the chunks the flush allocates (HDF5 allocates whole chunks) plus 1 MiB for metadata
        and finalising.
        """
        need = self.space_needed()
        problem = self._space_problem(need)
        if problem:
            self._failure = f"{problem}; recording stopped while the file is still consistent"
            raise RecorderError(f"writing {self.path} failed: {self._failure}")

    def _write_stream(self, st: _Stream) -> None:
        n = st.pending_rows
        if n == 0:
            return
        new = st.on_disk + n
        for name, ds in st.datasets.items():
            parts = st.pending[name]
            a = parts[0] if len(parts) == 1 else np.concatenate(parts)
            ds.resize(new, axis=0)
            ds[st.on_disk:new] = a
            parts.clear()
        st.on_disk = new
        st.pending_rows = 0
        st.pending_bytes = 0

    def _write_events(self) -> None:
        if self._blob_pending:
            old = self._blob_ds.shape[0]
            add = np.frombuffer(bytes(self._blob_pending), dtype=np.uint8)
            self._blob_ds.resize(old + add.shape[0], axis=0)
            self._blob_ds[old:] = add
            self._blob_pending.clear()
        if self._events:
            rows = np.array(self._events, dtype=EVENT_DTYPE)
            old = self._events_on_disk
            self._events_ds.resize(old + rows.shape[0], axis=0)
            self._events_ds[old:] = rows
            self._events_on_disk = old + rows.shape[0]
            self._events.clear()


# ---- helpers --------------------------------------------------------------------------------
LOCK_RETRY_S = 5.0
"""How long closing waits for readers (``bench watch``, ``bench inspect``) to let go of the file (s)."""


def _open_for_status(path: Path) -> h5py.File:
    """Reopen a released run file read-write. A reader holds a shared HDF5 file lock for the
    milliseconds of a read; retry while it does, up to :data:`LOCK_RETRY_S`."""
    deadline = time.monotonic() + LOCK_RETRY_S
    while True:
        try:
            return h5py.File(path, "r+", libver="latest")
        except OSError as exc:
            if "unable to lock file" not in str(exc) or time.monotonic() >= deadline:
                raise
            time.sleep(0.02)


def _chunk_bytes(ds: h5py.Dataset) -> int:
    """Size (bytes) of one chunk of ``ds``."""
    return int(np.prod(ds.chunks, dtype=np.int64)) * ds.dtype.itemsize


def _new_chunks(chunk_rows: int, rows: int, add: int) -> int:
    """Chunks HDF5 allocates when ``add`` rows are appended to ``rows`` rows (chunks of ``chunk_rows``)."""
    if add <= 0:
        return 0
    return -(-(rows + add) // chunk_rows) - -(-rows // chunk_rows)


def _convert(a: np.ndarray, dt: np.dtype, key: str, name: str) -> np.ndarray:
    """Copy ``a`` as dtype ``dt``, refusing lossy kinds of conversion."""
    kind = a.dtype.kind
    if kind not in "biuf":
        raise ValueError(f"stream {key!r}: column {name!r} has dtype {a.dtype}, expected numbers ({dt})")
    if dt.kind in "iu" and kind == "f":
        raise ValueError(f"stream {key!r}: column {name!r} holds floats ({a.dtype}) but is an integer column ({dt})")
    if dt.kind == "b" and kind != "b":
        raise ValueError(f"stream {key!r}: column {name!r} holds {a.dtype} but is a bool column")
    if dt.kind in "iu" and kind in "iu" and a.size and not np.can_cast(a.dtype, dt, "safe"):
        info = np.iinfo(dt)
        lo, hi = a.min(), a.max()
        if lo < info.min or hi > info.max:
            raise ValueError(f"stream {key!r}: column {name!r} has values {lo}..{hi} outside the range of {dt}")
    return np.array(a, dtype=dt, order="C", copy=True)


def _write_text(g: h5py.Group, text: str) -> None:
    """Store ``text`` exactly as a fixed-length utf-8 string dataset ``text`` (not variable length)."""
    raw = text.encode("utf-8", errors="surrogateescape")
    ds = g.create_dataset("text", data=np.array(raw, dtype=f"S{max(len(raw), 1)}"))
    ds.attrs["encoding"] = "utf-8"
    ds.attrs["length_bytes"] = np.int64(len(raw))


def _check_name(name: str, what: str) -> None:
    if not isinstance(name, str) or not name or "/" in name or name in (".", "..") or "\x00" in name:
        raise ValueError(f"{what} {name!r} must be a non-empty name without '/'")


def _cut_utf8(text: str, limit: int) -> bytes:
    raw = text.encode("utf-8", errors="replace")
    if len(raw) <= limit:
        return raw
    return raw[:limit].decode("utf-8", errors="ignore").encode("utf-8")


def _as_utc(t: datetime) -> datetime:
    return t.replace(tzinfo=timezone.utc) if t.tzinfo is None else t.astimezone(timezone.utc)


def _iso_z(t: datetime) -> str:
    return _as_utc(t).strftime("%Y-%m-%dT%H:%M:%SZ")


def _login_name() -> str:
    try:
        return getpass.getuser()
    except (OSError, KeyError):
        return "unknown"


def _os_reason(exc: BaseException) -> str:
    """Short reason of an OS/HDF5 error: the errno text when HDF5 reports one, else the message."""
    text = " ".join(str(exc).split())
    m = _HDF5_REASON.search(text)
    if m:
        errno_m = re.search(r"errno = (\d+)", text)
        what = text.split(" (", 1)[0]
        return f"{m.group(1)}" + (f" [errno {errno_m.group(1)}]" if errno_m else "") + f" ({what})"
    if isinstance(exc, OSError) and exc.strerror and exc.filename:
        return f"{exc.strerror}: {exc.filename}"
    return text or type(exc).__name__


def _mb(n: int) -> str:
    return f"{n / 1e6:.1f} MB"


def _close_quietly(f: h5py.File) -> None:
    try:
        f.close()
    except Exception:  # noqa: BLE001 - already reporting the first failure
        pass
