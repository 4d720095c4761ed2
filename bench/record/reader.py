"""Read run files written by :mod:`bench.record.writer`, also while they are being written.

Every path and attribute name comes from :mod:`bench.record.layout`.

A finished file is opened normally; a file in SWMR write mode (being written, or its writer died)
as an HDF5 SWMR reader; a file open for writing outside SWMR mode without file locking (which
HDF5 then refuses: being set up or finalised, or its writer stopped then). Anything that is not a readable bench run file (missing, empty,
truncated, corrupted, another HDF5 file) raises :class:`InputError`
``"<path>: not a readable bench run file: <reason>"``; h5py exceptions never leak out.

Units: run times in s since the start of the run, wall times in s since the Unix epoch, rates in Hz.
"""

from __future__ import annotations

import ctypes
import json
import math
import os
import re
import stat
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import date, datetime, timezone
from pathlib import Path
from typing import Any, Collection, Iterator

import h5py
import numpy as np
from rich.console import Console

from bench.errors import InputError
from bench.record import layout
from bench.record.chunks import StreamRows, checksum_state, excluded_rows, is_checksum_failure, read_rows, read_stream_rows

STALE_AFTER_S = 10.0
"""A ``running`` file whose heartbeat is at least this old (s of wall time) reads as ``crashed``."""

LOCK_WAIT_S = 2.0
"""How long (s) to retry while the writer holds the file lock (setting up, or finalising its status)."""

_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


@dataclass
class StreamSummary:
    """One stream: ``columns`` maps name → units (``time`` excluded, always s), ``shapes`` name →
    per-row shape; ``rows`` complete rows; first/last run time (s); mean rate (Hz) over the span."""

    key: str
    columns: dict[str, str]
    shapes: dict[str, tuple[int, ...]]
    rows: int
    t_start_s: float | None
    t_end_s: float | None
    rate_hz: float | None
    damage: str = ""
    """Why the first or last run time could not be read (a chunk failing its checksum), else ``""``."""


@dataclass
class EventRow:
    """One row of ``/events``: run time ``t_s`` (s), ``wall_unix`` (s), message decoded, raw ``data``."""

    t_s: float
    wall_unix: float
    kind: str
    source: str
    step: int
    message: str
    data: bytes


@dataclass
class StepSummary:
    """One executed step (0-based ``index``) from its step_start/step_end events.

    ``outcome`` is the first word of the step_end message (passed | failed | aborted | done), or
    ``interrupted`` when the step never ended (``running`` while the run is still being written).
    """

    index: int
    name: str
    outcome: str
    t_start_s: float | None
    t_end_s: float | None
    type: str = ""
    detail: str = ""

    @property
    def duration_s(self) -> float | None:
        """Run time (s) from start to end, None if either is unknown."""
        if self.t_start_s is None or self.t_end_s is None:
            return None
        return self.t_end_s - self.t_start_s


@dataclass
class InstrumentIdentity:
    """Who one instrument was: as it reported itself (``serial``, ``firmware``) and as the lab config
    declared it (``config_serial``, ``config_firmware``, ``calibration_due`` as ``YYYY-MM-DD``, UTC);
    ``""`` where unknown (older files, undeclared). ``calibration_overdue``: the due date was before
    the run's start date (UTC). ``overdue_confirmation``: the recorded answer to the overdue
    confirmation, ``answer (source, by who)``; ``""`` if none was recorded."""

    serial: str = ""
    firmware: str = ""
    config_serial: str = ""
    config_firmware: str = ""
    calibration_due: str = ""
    calibration_overdue: bool = False
    overdue_confirmation: str = ""


@dataclass
class PendingPrompt:
    """The question a live run waits on (its last ``prompt`` event, not answered yet): ``text`` as
    asked (with its accepted answers), prompt ``id``, ``attempt`` (1, 2, ...), the run time ``t_s`` (s)
    and wall time ``wall_unix`` (s since epoch) it was asked at, and its 0-based ``step``."""

    text: str
    id: str
    attempt: int
    t_s: float
    wall_unix: float
    step: int


@dataclass
class TrafficSummary:
    """The instrument traffic of one instrument (events ``command`` and ``reply``, kept for replay):
    how many of each, ``polls`` (rows of its monitor stream, 0 if it has none) and the run times
    (s) of its first and last frame."""

    instrument: str
    commands: int = 0
    replies: int = 0
    polls: int = 0
    t_first_s: float | None = None
    t_last_s: float | None = None

    def describe(self) -> str:
        """``tvac: 28,800 polls, 57,600 commands, 57,600 replies, last at 6:25:50``."""
        polls = f"{_count(self.polls, 'poll')}, " if self.polls else ""
        last = f", last at {format_run_time(self.t_last_s)}" if self.t_last_s is not None else ""
        return f"{self.instrument}: {polls}{_count(self.commands, 'command')}, {_count(self.replies, 'reply', 'replies')}{last}"


def _count(n: int, one: str, many: str = "") -> str:
    """``1 command``, ``28,800 commands``."""
    return f"{n:,} {one if n == 1 else (many or one + 's')}"


@dataclass
class RunSummary:
    """Everything about a run except the stream data.

    ``status`` is inferred: the file's status attribute, except that a ``running`` file whose
    heartbeat is stale reads as ``crashed`` (``status_detail`` says since when).
    """

    path: Path
    attrs: dict[str, Any]
    status: str
    procedure_text: str
    config_text: str
    instruments: dict[str, dict[str, str]]
    streams: list[StreamSummary]
    steps: list[StepSummary]
    events: list[EventRow]
    abort_reason: str
    status_detail: str = ""
    heartbeat_unix: float | None = None
    heartbeat_run_time_s: float | None = None
    event_counts: dict[str, int] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    identity: dict[str, str] = field(default_factory=dict)
    """Unit under test and station: every key of :data:`layout.IDENTITY_ATTRS` (``unit_serial``,
    ``unit_part``, ``unit_revision``, ``station``), ``""`` when the file does not record it."""
    instrument_identity: dict[str, InstrumentIdentity] = field(default_factory=dict)
    """Instrument name -> its reported and declared identity and calibration state."""
    waiting_for: PendingPrompt | None = None
    """The operator prompt a live run (status ``running``, heartbeat fresh) waits on, else None."""
    traffic: dict[str, TrafficSummary] = field(default_factory=dict)
    """Instrument -> its ``command``/``reply`` traffic, counted over the whole file (also when
    those events are not decoded)."""
    checksums: str = ""
    """Fletcher-32 checksums on the stream and event datasets: ``all``, ``some`` or ``none`` (a file
    written before checksums); the summary does not read every chunk (``bench inspect --verify`` does)."""

    @property
    def live_status(self) -> str:
        """``status``, except ``waiting`` (:data:`layout.STATUS_WAITING`) while a live run waits for
        the operator: what ``bench inspect`` and ``bench watch`` show."""
        return layout.STATUS_WAITING if self.waiting_for is not None else self.status

    @property
    def meaningful_events(self) -> list[EventRow]:
        """The decoded events except instrument traffic (:data:`layout.TRAFFIC_EVENT_KINDS`)."""
        return [e for e in self.events if e.kind not in layout.TRAFFIC_EVENT_KINDS]


def read_run_summary(path: Path, *, stale_after_s: float = STALE_AFTER_S, now_unix: float | None = None,
                     event_kinds: Collection[str] | None = None, traffic: bool = True) -> RunSummary:
    """Summarise the run file at ``path`` (complete, aborted, crashed or still being written).

    ``stale_after_s`` (s) is the heartbeat age from which a ``running`` file is reported as
    ``crashed``; ``now_unix`` (s since epoch) defaults to the current time. ``event_kinds``: decode
    only the events of these kinds (``events`` and ``steps`` then see only those; a long run logs
    every command and reply, hundreds of thousands of events); ``traffic=False`` decodes every event
    except the instrument traffic (:func:`read_traffic` reads it column-wise). ``event_counts``,
    ``traffic`` and ``waiting_for`` always count every event.
    Raises :class:`InputError` if the file is not a readable bench run file or is of a newer format.
    """
    path = Path(path)
    with _open_run(path) as (f, warnings):
        summary = _summarise(path, f, stale_after_s, time.time() if now_unix is None else now_unix, event_kinds, traffic)
        summary.warnings = warnings + summary.warnings  # the file's, then damaged event chunks
        return summary


def read_stream(path: Path, stream_key: str, columns: Collection[str] | None = None) -> dict[str, np.ndarray]:
    """All rows of stream ``stream_key`` (:func:`bench.record.layout.stream_key`, e.g.
    :func:`~bench.record.layout.monitor_key`): ``time`` (run time, s) and every column (only ``time`` and
    those of ``columns`` that exist, when given), each cut to the number of rows complete in every
    dataset. Raises :class:`InputError` for an unknown stream, and for damaged data (a chunk of
    those columns failing its checksum, or zeroed on disk), naming the rows and their run times;
    :func:`read_stream_checked` leaves those rows out instead."""
    got = read_stream_checked(path, stream_key, columns)
    if got.excluded:
        first = got.excluded[0]
        more = f" (and {len(got.excluded) - 1} more damaged range(s))" if len(got.excluded) > 1 else ""
        raise InputError(f"{path}: damaged data: {first.damage_text()}{more}; "
                         f"'bench inspect --verify {path}' lists every damaged chunk")
    return got.data


def read_stream_checked(path: Path, stream_key: str, columns: Collection[str] | None = None) -> StreamRows:
    """:func:`read_stream` without the rows of damaged chunks (a chunk failing its Fletcher-32
    checksum, or zeroed on disk: :mod:`bench.record.chunks`): ``.data`` holds the good rows of every
    column read, ``.excluded`` the row ranges left out with their run times and reasons."""
    path = Path(path)
    with _open_run(path) as (f, _warnings):
        groups = _stream_groups(f)
        if stream_key not in groups:
            raise InputError(f"{path}: no stream {stream_key!r} (streams: {', '.join(groups) or 'none'})")
        g = groups[stream_key]
        names = _column_order(g)
        limit = _size_limit(path)
        rows = min(_checked_rows(g[n], limit) for n in names)
        wanted = names if columns is None else [n for n in names if n == layout.TIME or n in columns]
        return read_stream_rows(f, path, stream_key, {n: g[n] for n in wanted}, rows)


# ---- opening ------------------------------------------------------------------------------------
@contextmanager
def _open_run(path: Path) -> Iterator[tuple[h5py.File, list[str]]]:
    """Open, check the format, yield ``(file, warnings)``; any failure inside becomes InputError."""
    f, truncated = _open_h5(path)
    warnings = [f"{truncated}: the last rows and events may be missing or read as zeros"] if truncated else []
    try:
        _check_format(path, f)
        yield f, warnings
    except InputError as exc:
        if truncated and exc.message.startswith(f"{path}: not a readable bench run file: "):
            detail = exc.message.split(": not a readable bench run file: ", 1)[1]
            raise _unreadable(path, f"{truncated} ({detail})") from None
        raise
    except Exception as exc:  # noqa: BLE001 - corrupted files make h5py/numpy raise anything
        raise _unreadable(path, f"{truncated} ({_describe(exc)})" if truncated else _describe(exc)) from None
    finally:
        try:
            f.close()
        except Exception:  # noqa: BLE001 - closing a read-only handle of a damaged file
            pass


@contextmanager
def open_run_file(path: Path) -> Iterator[h5py.File]:
    """The run file at ``path``, open read-only as every reader opens it (bounded in time on a
    damaged file: :func:`_open_h5`) and its format checked. Any failure while it is open becomes
    :class:`InputError` ``"<path>: not a readable bench run file: <reason>"``."""
    with _open_run(Path(path)) as (f, _warnings):
        yield f


def read_format_version(path: Path) -> int | None:
    """The ``format_version`` root attribute of the run file at ``path`` (None when it has none: not
    written by bench), read without judging it (``bench replay`` refuses older versions with its own
    message). Opened as every reader opens it, so a truncated or corrupted file is refused in
    bounded time; :class:`InputError` ``"<path>: not a readable bench run file: <reason>"``."""
    path = Path(path)
    f, truncated = _open_h5(path)
    try:
        if layout.ATTR_FORMAT_VERSION not in f.attrs:
            return None
        return int(np.asarray(f.attrs[layout.ATTR_FORMAT_VERSION]).item())
    except Exception as exc:  # noqa: BLE001 - corrupted files make h5py/numpy raise anything
        reason = f"bad {layout.ATTR_FORMAT_VERSION} attribute ({_describe(exc)})"
        raise _unreadable(path, f"{truncated} ({reason})" if truncated else reason) from None
    finally:
        try:
            f.close()
        except Exception:  # noqa: BLE001 - closing a read-only handle of a damaged file
            pass


def _open_h5(path: Path) -> tuple[h5py.File, str]:
    """Open a run file read-only, whatever state its writer is (or was) in.

    A finalised file opens normally. A file that is, or was when its writer died, in SWMR write
    mode refuses that ("already open for write") and is opened as an SWMR reader. A file whose
    writer holds the lock (setting up, or finalising the status) is retried for ``LOCK_WAIT_S``.
    The normal open comes first because an SWMR reader retries every metadata block whose
    checksum fails with exponential back-off (100 attempts by default: hours on a corrupted file).
    A file shorter than its superblock says (a write that failed half-way, a disk that filled up)
    is opened as an SWMR reader too, which does not check the length, with a warning.
    """
    try:
        if not path.exists():
            raise _unreadable(path, "no such file")
        if path.is_dir():
            raise _unreadable(path, "it is a directory")
        # O_NONBLOCK and fstat: a FIFO (also one swapped in after a check) would block forever
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
        try:
            st = os.fstat(fd)
            if not stat.S_ISREG(st.st_mode):
                raise _unreadable(path, "not a regular file (a device or FIFO)")
            size = st.st_size
            head = os.read(fd, 8)
        finally:
            os.close(fd)
    except ValueError:  # a NUL character in the name
        raise _unreadable(path, "expected a file name without NUL characters") from None
    except OSError as exc:
        raise _unreadable(path, exc.strerror or str(exc)) from None
    if size == 0:
        raise _unreadable(path, "the file is empty")
    if head != _HDF5_SIGNATURE:
        raise _unreadable(path, "not an HDF5 file (no HDF5 signature at its start)")
    deadline = time.monotonic() + LOCK_WAIT_S
    truncated: BaseException | None = None
    while True:
        try:
            return h5py.File(path, "r"), ""
        except Exception as exc:  # noqa: BLE001 - h5py raises OSError subclasses, RuntimeError...
            text = str(exc)
            if "unable to lock file" in text and time.monotonic() < deadline:
                time.sleep(0.05)
                continue
            if "truncated file" in text:
                truncated = exc
                if _cut_global_heap_loops(path, size):
                    raise _unreadable(path, f"{_describe(exc)}, inside an HDF5 global heap collection (where the "
                                            "text attributes are) that HDF5 cannot read without looping forever") from None
                break
            if "already open for write" in text:
                break
            raise _unreadable(path, _describe(exc)) from None
    try:
        f = _open_swmr_reader(path)
    except Exception as exc:  # noqa: BLE001
        if truncated is not None:
            raise _unreadable(path, _describe(truncated)) from None
        if "not already open for SWMR writing" not in str(exc):
            raise _unreadable(path, _describe(exc)) from None
    else:
        return f, _describe(truncated) if truncated is not None else ""
    try:
        # Never switched to SWMR mode: the writer died (or is) before recording started.
        return h5py.File(path, "r", locking=False), ""
    except Exception as exc:  # noqa: BLE001
        raise _unreadable(path, _describe(exc, path)) from None


_GCOL_SCAN_BYTES = 1 << 20


def _cut_global_heap_loops(path: Path, size: int) -> bool:
    """Whether a global heap collection runs past the end of the truncated file at ``path`` such that
    HDF5 would hang reading it.

    HDF5 reads the missing bytes of a truncated file as zeros, and its global heap parser
    (``H5HG__cache_heap_deserialize``, HDF5 2.0) never advances past a zeroed object header
    (index 0, size 0): reading any variable-length string of that collection then loops forever.
    The collections that may reach past the end start in the last ``_GCOL_SCAN_BYTES`` (collections
    are 4 KiB unless a single string is longer); each one found there is walked as HDF5 walks it.
    """
    start = max(0, size - _GCOL_SCAN_BYTES)
    try:
        with open(path, "rb") as fh:
            fh.seek(start)
            tail = fh.read()
    except OSError:
        return False
    pos = tail.find(b"GCOL")
    while pos >= 0:
        header = tail[pos:pos + 16].ljust(16, b"\0")  # signature, version 1, 3 reserved, size (8 bytes)
        if header[4] == 1:
            end = pos + int.from_bytes(header[8:16], "little")
            if end > len(tail):
                body = tail[pos:end] + bytes(min(end - len(tail), _GCOL_SCAN_BYTES))
                obj = 16
                while obj + 16 <= len(body):
                    index = int.from_bytes(body[obj:obj + 2], "little")
                    length = int.from_bytes(body[obj + 8:obj + 16], "little")
                    need = length if index == 0 else 16 + (length + 7) // 8 * 8
                    if need == 0:
                        return True
                    obj += need
        pos = tail.find(b"GCOL", pos + 1)
    return False


SWMR_READ_ATTEMPTS = 26
"""Metadata read attempts of an SWMR reader (HDF5 default 100). A block read while the writer
rewrites it fails its checksum and is read again after a doubling pause; 26 attempts bound that
to about 70 ms per block instead of practically forever for a block that is truly corrupted."""

_set_read_attempts: Any = None


def _open_swmr_reader(path: Path) -> h5py.File:
    """``h5py.File(path, "r", swmr=True)``, with ``SWMR_READ_ATTEMPTS`` when the HDF5 library
    h5py uses can be reached (h5py has no binding for ``H5Pset_metadata_read_attempts``)."""
    setter = _read_attempts_setter()
    if setter is None:
        return h5py.File(path, "r", swmr=True)
    fapl = h5py.h5p.create(h5py.h5p.FILE_ACCESS)
    if setter(fapl.id, SWMR_READ_ATTEMPTS) < 0:
        return h5py.File(path, "r", swmr=True)
    fid = h5py.h5f.open(os.fsencode(path), h5py.h5f.ACC_RDONLY | h5py.h5f.ACC_SWMR_READ, fapl=fapl)
    return h5py.File(fid)


def _read_attempts_setter() -> Any:
    """``H5Pset_metadata_read_attempts`` of the HDF5 library loaded by h5py, or None."""
    global _set_read_attempts
    if _set_read_attempts is not None:
        return _set_read_attempts or None
    found: Any = False
    candidates = sorted(Path(h5py.__file__).parent.parent.glob("h5py.libs/libhdf5-*.so*"))
    candidates = [c for c in candidates if "_hl" not in c.name]
    try:
        with open("/proc/self/maps") as maps:
            for line in maps:
                lib = line.rsplit(" ", 1)[-1].strip()
                if "/libhdf5" in lib and "_hl" not in Path(lib).name and Path(lib) not in candidates:
                    candidates.append(Path(lib))
    except OSError:
        pass
    for lib_path in candidates:
        try:
            fn = ctypes.CDLL(str(lib_path)).H5Pset_metadata_read_attempts
        except (OSError, AttributeError):
            continue
        fn.argtypes = [ctypes.c_int64, ctypes.c_uint]
        fn.restype = ctypes.c_int
        found = fn
        break
    _set_read_attempts = found
    return found or None


def _check_format(path: Path, f: h5py.File) -> None:
    try:
        if layout.ATTR_FORMAT_VERSION not in f.attrs:
            raise _unreadable(path, f"no {layout.ATTR_FORMAT_VERSION} attribute (not written by bench)")
        version = int(np.asarray(f.attrs[layout.ATTR_FORMAT_VERSION]).item())
    except InputError:
        raise
    except Exception as exc:  # noqa: BLE001
        raise _unreadable(path, f"bad {layout.ATTR_FORMAT_VERSION} attribute ({_describe(exc)})") from None
    if version > layout.FORMAT_VERSION:
        raise InputError(
            f"{path}: run file {layout.ATTR_FORMAT_VERSION} {version} is newer than this bench reads "
            f"(up to {layout.FORMAT_VERSION}); upgrade bench to read it"
        )
    if version < 1:
        raise _unreadable(path, f"invalid {layout.ATTR_FORMAT_VERSION} {version}")
    for name in layout.REQUIRED:
        try:
            present = name in f
        except Exception as exc:  # noqa: BLE001
            raise _unreadable(path, f"{layout.absolute(name)}: {_describe(exc)}") from None
        if not present:
            raise _unreadable(path, f"{layout.absolute(name)} is missing")


def _unreadable(path: Path, reason: str) -> InputError:
    return InputError(f"{path}: not a readable bench run file: {reason}")


def _describe(exc: BaseException, path: Path | None = None) -> str:
    """A short reason for an h5py/HDF5 failure (of the file at ``path``, whose size it then gives)."""
    text = str(exc)
    if isinstance(exc, DamagedFile):
        return text
    if "already open for write" in text:
        # Set up (before SWMR mode) and finalising (after it) both leave this mark while they run; a
        # writer killed then, or whose last writes failed (a full disk), leaves it for good. Which
        # one, and whether rows were recorded, cannot be told without opening the file.
        try:
            size = f"its {path.stat().st_size:,} bytes" if path is not None else "its contents"
        except OSError:
            size = "its contents"
        return (
            "HDF5 refuses to open it: it is marked open for writing outside SWMR mode, by a writer setting it up or "
            "writing its final status right now, or by one that stopped without closing it (killed, or its disk was "
            f"full); {size} cannot be read, and unless a bench process is writing it, the file is damaged"
        )
    if "truncated file" in text:
        m = re.search(r"truncated file: ([^)]*)", text)
        return f"the file is truncated ({m.group(1) if m else text})"
    if "unable to lock file" in text:
        return "the file is locked by the process writing it (it is not in SWMR mode yet)"
    if "file signature not found" in text:
        return "not an HDF5 file"
    if "incorrect metadata checksum" in text:
        return "corrupted: HDF5 metadata fails its checksum"
    m = re.search(r"\(([^()]*)\)\s*$", text)
    detail = m.group(1) if m else text
    return f"{type(exc).__name__}: {detail}" if detail else type(exc).__name__


# ---- reading ------------------------------------------------------------------------------------
def _size_limit(path: Path) -> int:
    """Most bytes any dataset of this file can hold: data is stored uncompressed, so a dataset
    larger than the file (plus a few chunks a live writer may just be adding) is corrupted."""
    return path.stat().st_size + 4 * 1024 * 1024


def first_row_at_or_after(ds: h5py.Dataset, t: float, lo: int, hi: int) -> int:
    """First row in ``lo..hi`` of the time column ``ds`` (s, ascending) whose time is >= ``t``, with
    O(log n) point reads (a live view of a long run reads a few rows, never the column)."""
    while lo < hi:
        mid = (lo + hi) // 2
        if float(ds[mid]) < t:
            lo = mid + 1
        else:
            hi = mid
    return lo


def _checked_rows(ds: h5py.Dataset, limit: int) -> int:
    """Rows of ``ds`` after checking its size is plausible (a corrupted extent could ask HDF5 to
    produce terabytes of fill values)."""
    if not isinstance(ds, h5py.Dataset) or ds.ndim < 1:
        raise ValueError(f"{ds.name} is not a row dataset")
    if ds.size * ds.dtype.itemsize > limit:
        raise ValueError(f"{ds.name} claims {ds.shape} x {ds.dtype.itemsize} bytes, more than the file holds (corrupted)")
    return int(ds.shape[0])


def _summarise(path: Path, f: h5py.File, stale_after_s: float, now_unix: float,
               event_kinds: Collection[str] | None = None, traffic: bool = True, *,
               scan: "_EventScan | None" = None, damage: list[str] | None = None) -> RunSummary:
    """The summary of the open run file ``f``; ``scan``: its events already scanned (with
    ``damage``, what that scan found), else scanned here."""
    limit = _size_limit(path)
    attrs = {k: _plain(v) for k, v in f.attrs.items()}
    hb = read_heartbeat(f, limit)
    hb_unix = float(hb[0]) if hb.size >= 1 else None
    hb_run = float(hb[1]) if hb.size >= 2 else None
    status = str(attrs.get(layout.ATTR_STATUS, ""))
    detail = ""
    if status == layout.STATUS_RUNNING:
        if hb_unix is None or not np.isfinite(hb_unix):
            status, detail = layout.STATUS_CRASHED, "no valid heartbeat"
        else:
            age = now_unix - hb_unix
            since = _iso(hb_unix)
            at = f", run time {hb_run:.1f} s" if hb_run is not None and np.isfinite(hb_run) else ""
            if age >= stale_after_s:
                status, detail = layout.STATUS_CRASHED, f"no heartbeat since {since} ({age:.0f} s ago{at}); data up to that flush is in the file"
            else:
                detail = f"being written: last heartbeat {since} ({age:.1f} s ago{at})"
    if scan is None:
        damage = []
        scan = _scan_events(f, limit, damage, event_kinds)
    damage = damage if damage is not None else []
    rows, blob = scan.rows, scan.blob
    events = _decode_events(rows, blob, event_kinds, traffic)
    streams = [_stream_summary(key, g, limit) for key, g in _stream_groups(f).items()]
    waiting = _pending_prompt(rows, blob) if status == layout.STATUS_RUNNING else None
    if waiting is not None:
        asked = f"asked {max(now_unix - waiting.wall_unix, 0.0):.0f} s ago at run time {waiting.t_s:.1f} s"
        detail = f"waiting for operator: {waiting.text} ({asked}); {detail}"
    return RunSummary(
        path=path,
        attrs=attrs,
        status=status,
        procedure_text=_read_text(f[layout.PROCEDURE_TEXT], limit),
        config_text=_read_text(f[layout.CONFIG_TEXT], limit),
        instruments={name: {k: str(_plain(v)) for k, v in g.attrs.items()} for name, g in members(f[layout.INSTRUMENTS])},
        streams=streams,
        steps=_steps(events, live=status == layout.STATUS_RUNNING),
        events=events,
        abort_reason=str(attrs.get(layout.ATTR_ABORT_REASON, "")),
        status_detail=detail,
        heartbeat_unix=hb_unix,
        heartbeat_run_time_s=hb_run,
        event_counts=scan.counts,
        identity={k: str(attrs.get(k, "")) for k in layout.IDENTITY_ATTRS},
        instrument_identity=_instrument_identities(f, attrs, events),
        waiting_for=waiting,
        traffic=_traffic_of(scan.traffic, streams),
        warnings=damage,
        checksums=checksum_state([g[n] for g in _stream_groups(f).values() for n in _column_order(g)] + list(event_datasets(f))),
    )


def _instrument_identities(f: h5py.File, attrs: dict[str, Any], events: list[EventRow]) -> dict[str, InstrumentIdentity]:
    """Each instrument's :class:`InstrumentIdentity`: its identity attributes, the overdue flag
    (calibration due before the run's start date, UTC) and the recorded overdue confirmation."""
    started = _date_of(str(attrs.get(layout.ATTR_STARTED_UTC, ""))[:10])
    answers: dict[str, str] = {}
    for e in events:
        if e.kind == layout.EVENT_OPERATOR and e.source == layout.SOURCE_CALIBRATION:
            try:
                d = json.loads(e.message)
                answers[str(d["instrument"])] = f"{d['answer']} ({d['source']}, by {d['operator']})"
            except (ValueError, KeyError, TypeError):
                continue
    out: dict[str, InstrumentIdentity] = {}
    for name, g in members(f[layout.INSTRUMENTS]):
        a = {k: str(_plain(v)) for k, v in g.attrs.items()}
        due = a.get(layout.ATTR_CALIBRATION_DUE, "")
        due_date = _date_of(due)
        out[name] = InstrumentIdentity(
            serial=a.get(layout.ATTR_REPORTED_SERIAL, ""), firmware=a.get(layout.ATTR_REPORTED_FIRMWARE, ""),
            config_serial=a.get(layout.ATTR_CONFIG_SERIAL, ""), config_firmware=a.get(layout.ATTR_CONFIG_FIRMWARE, ""),
            calibration_due=due,
            calibration_overdue=due_date is not None and started is not None and due_date < started,
            overdue_confirmation=answers.get(name, ""),
        )
    return out


def _date_of(text: str) -> date | None:
    """``YYYY-MM-DD`` as a date, None if it is not one."""
    try:
        return date.fromisoformat(text) if len(text) == 10 else None
    except ValueError:
        return None


def _plain(v: Any) -> Any:
    if isinstance(v, bytes):
        return v.decode("utf-8", errors="replace")
    if isinstance(v, np.ndarray):
        return [_plain(x) for x in v.tolist()]
    if isinstance(v, np.generic):
        return _plain(v.item())
    return v


def _read_text(ds: h5py.Dataset, limit: int) -> str:
    if not isinstance(ds, h5py.Dataset) or ds.size * ds.dtype.itemsize > limit:
        raise ValueError(f"{ds.name} is not a plausible text dataset (corrupted)")
    raw = ds[()]
    raw = bytes(raw) if isinstance(raw, (bytes, np.bytes_)) else np.asarray(raw, dtype=np.uint8).tobytes()
    n = ds.attrs.get(layout.ATTR_LENGTH_BYTES)
    if n is not None:
        n = min(int(np.asarray(n).item()), limit)
        raw = raw.ljust(n, b"\0")[:n]  # numpy drops trailing NULs of fixed-length strings
    return raw.decode(layout.TEXT_ENCODING, errors="surrogateescape")


def _stream_groups(f: h5py.File) -> dict[str, h5py.Group]:
    """Stream key -> group: the groups under ``/streams`` (one or two levels down) that hold a
    ``time`` dataset."""
    out: dict[str, h5py.Group] = {}
    for inst, g in members(f[layout.STREAMS]):
        if not isinstance(g, h5py.Group):
            continue
        if isinstance(g.get(layout.TIME), h5py.Dataset):
            out[layout.stream_key(inst)] = g
            continue
        for sub, sg in members(g):
            if isinstance(sg, h5py.Group) and isinstance(sg.get(layout.TIME), h5py.Dataset):
                out[layout.stream_key(inst, sub)] = sg
    return out


def members(g: h5py.Group) -> list[tuple[str, Any]]:
    """``(name, object)`` of every member of group ``g``. h5py's ``items()`` gives None for a member
    it cannot open (a link to nothing, a damaged object header), which later failed as
    "'NoneType' object has no attribute 'attrs'"; here such a member raises ``ValueError`` naming
    it and why, which the readers turn into "not a readable bench run file: /instruments/board: ..."."""
    out = []
    for name in g:
        try:
            obj = g[name]
        except Exception as exc:  # noqa: BLE001 - KeyError (missing target), OSError (damaged header) ...
            link = g.get(name, getlink=True)
            where = f"{g.name.rstrip('/')}/{name}"
            if isinstance(link, h5py.SoftLink):
                raise DamagedFile(f"{where} is a link to {link.path}, which does not exist: the file is damaged") from None
            raise DamagedFile(f"{where} cannot be opened ({_describe(exc)}): the file is damaged") from None
        out.append((name, obj))
    return out


class DamagedFile(ValueError):
    """A part of a run file that cannot be read, with a message that says which (shown as it is)."""


def _column_order(g: h5py.Group) -> list[str]:
    """The datasets of stream group ``g``: ``time``, then the declared columns in their order,
    then any others by name."""
    declared = g.attrs.get(layout.ATTR_COLUMNS)
    names = [n for n in str(_plain(declared)).split(layout.COLUMN_SEPARATOR) if n] if declared is not None else []
    present = [n for n in g if isinstance(g[n], h5py.Dataset)]
    names = [n for n in names if n in present] + sorted(n for n in present if n not in names)
    return [layout.TIME] + [n for n in names if n != layout.TIME]


def _units(ds: h5py.Dataset) -> str:
    """The ``units`` attribute of a column, ``""`` when absent."""
    return str(_plain(ds.attrs.get(layout.ATTR_UNITS, "")))


def _stream_summary(key: str, g: h5py.Group, limit: int) -> StreamSummary:
    names = _column_order(g)
    rows = min(_checked_rows(g[n], limit) for n in names)
    columns = {n: _units(g[n]) for n in names if n != layout.TIME}
    shapes = {n: tuple(int(s) for s in g[n].shape[1:]) for n in names if n != layout.TIME}
    damage: list[str] = []
    t0 = _run_time(g, 0, damage) if rows else None
    t1 = (t0 if rows == 1 else _run_time(g, rows - 1, damage)) if rows else None
    rate = None
    if rows > 1 and t0 is not None and t1 is not None and t1 > t0:
        rate = (rows - 1) / (t1 - t0)
    return StreamSummary(key, columns, shapes, rows, t0, t1, rate, "; ".join(damage))


def _run_time(g: h5py.Group, row: int, damage: list[str]) -> float | None:
    """The run time (s) of ``row`` of stream group ``g``; None, and why in ``damage``, when its chunk
    fails its checksum (any other failure: not a readable run file)."""
    try:
        return float(g[layout.TIME][row])
    except OSError as exc:
        if not is_checksum_failure(exc):
            raise
        damage.append(f"the run time of row {row} fails its checksum")
        return None


def read_heartbeat(f: h5py.File, limit: int) -> np.ndarray:
    """The heartbeat values (:data:`layout.HEARTBEAT_FIELDS`: wall time s since epoch, run time s)
    after checking the dataset holds exactly those."""
    ds = f[layout.HEARTBEAT]
    if _checked_rows(ds, limit) != len(layout.HEARTBEAT_FIELDS):
        raise ValueError(f"{layout.absolute(layout.HEARTBEAT)} does not hold {len(layout.HEARTBEAT_FIELDS)} values")
    return np.asarray(ds[()], dtype=np.float64).reshape(-1)


def event_datasets(f: h5py.File) -> tuple[h5py.Dataset, h5py.Dataset]:
    """``(/events, /events_blob)`` after checking the table has the bench event fields."""
    ds = f[layout.EVENTS]
    if not set(layout.EVENT_FIELDS) <= set(ds.dtype.names or ()):
        raise ValueError(f"{layout.absolute(layout.EVENTS)} does not have the bench event fields")
    return ds, f[layout.EVENTS_BLOB]


def event_row(r: np.void, message: str, data: bytes) -> EventRow:
    """One row of ``/events`` (:data:`layout.EVENT_DTYPE`), decoded, with its message and data."""
    return EventRow(
        t_s=float(r["t_s"]),
        wall_unix=float(r["wall_unix"]),
        kind=bytes(r["kind"]).decode("ascii", errors="replace"),
        source=bytes(r["source"]).decode("utf-8", errors="replace"),
        step=int(r["step"]),
        message=message,
        data=data,
    )


def _read_events(f: h5py.File, limit: int, kinds: Collection[str] | None = None) -> list[EventRow]:
    rows, blob = _event_table(f, limit, lazy_blob=kinds is not None)
    return _decode_events(rows, blob, kinds)


def _blob_note(blob_name: str, start: int, end: int, reason: str) -> str:
    return (f"bytes {start}–{end - 1} of {blob_name}: {reason}: the event messages stored there read "
            "as NUL characters (bench inspect --verify)")


class _LazyBlob:
    """``/events_blob`` read piece by piece, for a reader that decodes a few events of a long run
    (the catalogue, a summary of steps and checks): the traffic bytes, most of the blob, are never
    read. Pieces of a chunk failing its checksum read as zeros and are said in ``damage``."""

    def __init__(self, ds: h5py.Dataset, n: int, damage: list[str] | None):
        self.ds, self.n, self.damage = ds, n, damage

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, s: slice) -> bytes:
        a, b = int(s.start), min(int(s.stop), self.n)
        if b <= a:
            return b""
        try:
            return np.asarray(self.ds[a:b], dtype=np.uint8).tobytes()
        except OSError as exc:
            if not is_checksum_failure(exc):
                raise
        step = int(self.ds.chunks[0]) if self.ds.chunks else b - a
        lo = a - a % step  # read_rows starts at a chunk boundary
        part, bad = read_rows(self.ds, lo, min(b + (-b) % step, self.n))
        if self.damage is not None:
            self.damage += [_blob_note(self.ds.name, x.row_start, x.row_end, x.reason) for x in bad]
        return np.asarray(part[a - lo:b - lo], dtype=np.uint8).tobytes()


def _event_table(f: h5py.File, limit: int, damage: list[str] | None = None, *,
                 lazy_blob: bool = False) -> tuple[np.ndarray, bytes | _LazyBlob]:
    """Every row of ``/events`` (:data:`layout.EVENT_DTYPE`) and ``/events_blob``: whole, or read
    piece by piece as events are decoded (``lazy_blob``: for readers that decode a few kinds; a long
    run's traffic is most of the blob and is then never read). Rows of a chunk failing its checksum
    are left out, and bytes of such a blob chunk read as zeros; each is said in ``damage``."""
    ds, blob_ds = event_datasets(f)
    rows, bad = read_rows(ds, 0, _checked_rows(ds, limit))
    notes = [f"{e.rows_text()} of {ds.name}: {e.reason}: those events are left out (bench inspect --verify)"
             for e in excluded_rows(ds.name, bad, rows["t_s"], ds.name.rsplit("/", 1)[-1])]
    blob: bytes | _LazyBlob
    if lazy_blob:
        blob = _LazyBlob(blob_ds, _checked_rows(blob_ds, limit), damage)
    else:
        blob_rows, bad_blob = read_rows(blob_ds, 0, _checked_rows(blob_ds, limit))
        blob = np.asarray(blob_rows, dtype=np.uint8).tobytes()
        notes += [_blob_note(blob_ds.name, b.row_start, b.row_end, b.reason) for b in bad_blob]
    if bad:
        keep = np.ones(rows.shape[0], dtype=bool)
        for b in bad:
            keep[b.row_start:b.row_end] = False
        rows = rows[keep]
    if damage is not None:
        damage += notes
    return rows, blob


def _kind_mask(rows: np.ndarray, kinds: Collection[str]) -> np.ndarray:
    """Which rows are of one of ``kinds``."""
    return np.isin(rows["kind"], np.array([k.encode("ascii") for k in kinds], dtype=rows.dtype["kind"]))


def _decode_events(rows: np.ndarray, blob: bytes, kinds: Collection[str] | None = None, traffic: bool = True) -> list[EventRow]:
    """The rows as :class:`EventRow` (only ``kinds`` if given; without the traffic if not ``traffic``)."""
    if kinds is not None:
        rows = rows[_kind_mask(rows, kinds)]
    if not traffic:
        rows = rows[~_kind_mask(rows, layout.TRAFFIC_EVENT_KINDS)]
    if isinstance(blob, _LazyBlob):  # a few events: each piece read as it is decoded
        return [_event_of(r, blob) for r in rows]
    return _decode_rows(rows, blob)


def _decode_rows(rows: np.ndarray, blob: bytes) -> list[EventRow]:
    """:func:`_event_of` of every row, column by column (an 8-h run has half a million events):
    the same :class:`EventRow` values, kinds and sources decoded once per distinct name."""
    return [EventRow(*e) for e in zip(*_event_columns(rows, blob))]


def _event_columns(rows: np.ndarray, blob: bytes) -> tuple[list, ...]:
    """The fields of :class:`EventRow` of every row, as lists in field order (run time s, wall
    time s, kind, source, step, message, data): kinds and sources decoded once per distinct name,
    messages and data cut from the blob as :func:`_slice` does."""
    names = {k: k.decode("ascii", errors="replace") for k in set(rows["kind"].tolist())}
    kinds = [names[k] for k in rows["kind"].tolist()]
    names = {s: s.decode("utf-8", errors="replace") for s in set(rows["source"].tolist())}
    sources = [names[s] for s in rows["source"].tolist()]
    n_blob = len(blob)
    messages = [blob[o:o + n].decode("utf-8", errors="replace") if o < n_blob and n > 0 else ""
                for o, n in zip(rows["msg_off"].tolist(), rows["msg_len"].tolist())]
    data = [blob[o:o + n] if o < n_blob and n > 0 else b"" for o, n in zip(rows["data_off"].tolist(), rows["data_len"].tolist())]
    return rows["t_s"].tolist(), rows["wall_unix"].tolist(), kinds, sources, rows["step"].tolist(), messages, data


@dataclass
class Traffic:
    """The instrument traffic of a run file (every ``command`` and ``reply`` event, in order),
    column-wise: a long run has half a million of them, read without an object each."""

    t_s: list[float]
    """Run time of each event (s)."""
    kind: list[str]
    """``command`` or ``reply``."""
    source: list[str]
    """The instrument."""
    step: list[int]
    """0-based step index, :data:`layout.NO_STEP` outside steps."""
    message: list[str]
    """What the driver named the exchange (e.g. ``read 100``, ``SYNC``)."""
    data: list[bytes]
    """The bytes on the wire."""
    damage: list[str] = field(default_factory=list)
    """Events left out because their chunk failed its checksum, and why."""

    def __len__(self) -> int:
        return len(self.t_s)


def read_traffic(path: Path, kinds: Collection[str] = layout.TRAFFIC_EVENT_KINDS) -> Traffic:
    """The traffic events of the run file at ``path`` (only ``kinds``: ``command``, ``reply``);
    :class:`InputError` as :func:`read_run_summary`."""
    path = Path(path)
    damage: list[str] = []
    with _open_run(path) as (f, _warnings):
        rows, blob = _event_table(f, _size_limit(path), damage)
        return _traffic_of_rows(rows, blob, kinds, damage)


def read_summary_and_traffic(path: Path, kinds: Collection[str] = layout.TRAFFIC_EVENT_KINDS) -> tuple[RunSummary, Traffic]:
    """``read_run_summary(path, traffic=False)`` and ``read_traffic(path, kinds)`` with the file
    opened and its events read once (a replay needs both of a long run)."""
    path = Path(path)
    with _open_run(path) as (f, warnings):
        damage: list[str] = []
        scan = _scan_events(f, _size_limit(path), damage, None)
        summary = _summarise(path, f, STALE_AFTER_S, time.time(), None, False, scan=scan, damage=damage)
        summary.warnings = warnings + summary.warnings
        return summary, _traffic_of_rows(scan.rows, scan.blob, kinds, list(damage))


def _traffic_of_rows(rows: np.ndarray, blob: bytes, kinds: Collection[str], damage: list[str]) -> Traffic:
    """:class:`Traffic` of the ``kinds`` events of ``rows`` (all read, with the whole blob)."""
    t, _wall, kind, source, step, message, data = _event_columns(rows[_kind_mask(rows, kinds)], blob)
    return Traffic(t, kind, source, step, message, data, damage)


def _event_of(r: np.void, blob: bytes) -> EventRow:
    return event_row(r, _slice(blob, int(r["msg_off"]), int(r["msg_len"])).decode("utf-8", errors="replace"),
                     _slice(blob, int(r["data_off"]), int(r["data_len"])))


def _kind_counts(rows: np.ndarray, into: dict[str, int] | None = None) -> dict[str, int]:
    """Events per kind over ``rows`` (rows the writer has not filled yet left out), added to ``into``."""
    out = {} if into is None else into
    kinds, n = np.unique(rows["kind"], return_counts=True)
    for k, c in zip(kinds, n):
        if k:
            name = k.decode("ascii", errors="replace")
            out[name] = out.get(name, 0) + int(c)
    return out


def _traffic_counts(rows: np.ndarray, into: dict[str, list[float]] | None = None) -> dict[str, list[float]]:
    """Per instrument: [commands, replies, first t_s, last t_s] of its traffic events in ``rows``,
    added to ``into`` (vectorised)."""
    out = {} if into is None else into
    sel = rows[_kind_mask(rows, layout.TRAFFIC_EVENT_KINDS)]
    for src in np.unique(sel["source"]):
        mine = sel[sel["source"] == src]
        name = bytes(src).decode("utf-8", errors="replace")
        t = mine["t_s"]
        acc = out.setdefault(name, [0, 0, math.inf, -math.inf])
        acc[0] += int(np.count_nonzero(mine["kind"] == b"command"))
        acc[1] += int(np.count_nonzero(mine["kind"] == b"reply"))
        acc[2], acc[3] = min(acc[2], float(t.min())), max(acc[3], float(t.max()))
    return out


def _traffic_of(counts: dict[str, list[float]], streams: list[StreamSummary]) -> dict[str, TrafficSummary]:
    """The :class:`TrafficSummary` of each instrument from :func:`_traffic_counts` and its monitor rows."""
    monitor_rows = {s.key: s.rows for s in streams}
    return {name: TrafficSummary(name, commands=int(c), replies=int(r), polls=monitor_rows.get(layout.monitor_key(name), 0),
                                 t_first_s=float(t0), t_last_s=float(t1))
            for name, (c, r, t0, t1) in counts.items()}


@dataclass
class _EventScan:
    """What a summary needs of ``/events``: the rows it decodes, the blob, counts per kind and the
    traffic per instrument (:func:`_traffic_counts`)."""

    rows: np.ndarray
    blob: "bytes | _LazyBlob"
    counts: dict[str, int]
    traffic: dict[str, list[float]]


SCAN_BLOCK_ROWS = 1 << 16
"""Rows of ``/events`` a filtered summary reads at a time (≈ 6 MB): an 8-h run's half a million
events are counted block by block and only the kinds asked for are kept."""


def _scan_events(f: h5py.File, limit: int, damage: list[str], kinds: Collection[str] | None) -> _EventScan:
    """``/events`` for a summary. Without ``kinds``: every row and the whole blob
    (:func:`_event_table`). With ``kinds``: the rows are read in blocks of :data:`SCAN_BLOCK_ROWS`,
    counted, and only the rows of ``kinds`` (and of the prompt and what closes one) kept; the blob is
    read piece by piece as they are decoded. A block with a damaged chunk falls back to the whole read
    (which says what was left out)."""
    if kinds is None:
        rows, blob = _event_table(f, limit, damage)
        return _EventScan(rows, blob, _kind_counts(rows), _traffic_counts(rows))
    ds, blob_ds = event_datasets(f)
    n = _checked_rows(ds, limit)
    step = SCAN_BLOCK_ROWS
    if ds.chunks:
        step = max(int(ds.chunks[0]), step - step % int(ds.chunks[0]))  # blocks start at chunk boundaries
    keep = (*kinds, layout.EVENT_PROMPT, *layout.PROMPT_CLOSING_KINDS)
    kept: list[np.ndarray] = []
    counts: dict[str, int] = {}
    traffic: dict[str, list[float]] = {}
    for a in range(0, n, step):
        block, bad = read_rows(ds, a, min(a + step, n))
        if bad:
            rows, blob = _event_table(f, limit, damage, lazy_blob=True)
            return _EventScan(rows, blob, _kind_counts(rows), _traffic_counts(rows))
        _kind_counts(block, counts)
        _traffic_counts(block, traffic)
        kept.append(block[_kind_mask(block, keep)])
    rows = np.concatenate(kept) if kept else np.zeros(0, dtype=ds.dtype)
    return _EventScan(rows, _LazyBlob(blob_ds, _checked_rows(blob_ds, limit), damage), counts, traffic)


def _pending_prompt(rows: np.ndarray, blob: bytes) -> PendingPrompt | None:
    """The last ``prompt`` event if no answer, step end, abort or end of run came after it."""
    asked = np.flatnonzero(rows["kind"] == layout.EVENT_PROMPT.encode("ascii"))
    if not asked.size:
        return None
    last = int(asked[-1])
    if _kind_mask(rows[last + 1:], layout.PROMPT_CLOSING_KINDS).any():
        return None
    e = _event_of(rows[last], blob)
    try:
        info = json.loads(e.data.decode("utf-8")) if e.data else {}
    except (UnicodeDecodeError, json.JSONDecodeError):
        info = {}
    info = info if isinstance(info, dict) else {}
    attempt = info.get("attempt", 1)
    return PendingPrompt(e.message, str(info.get("id", "")), attempt if isinstance(attempt, int) else 1, e.t_s, e.wall_unix, e.step)


def _slice(blob: bytes, off: int, n: int) -> bytes:
    """Bytes ``off``..``off+n`` of the blob; what a reader racing the writer cannot see yet is cut off."""
    if off >= len(blob) or n <= 0:
        return b""
    return blob[off : off + n]


def _steps(events: list[EventRow], live: bool) -> list[StepSummary]:
    steps: list[StepSummary] = []
    open_steps: dict[int, StepSummary] = {}
    for e in events:
        if e.kind == layout.EVENT_STEP_START:
            s = StepSummary(e.step, e.message, "", e.t_s, None, e.source)
            steps.append(s)
            open_steps[e.step] = s
        elif e.kind == layout.EVENT_STEP_END:
            s = open_steps.pop(e.step, None)
            if s is None:
                s = StepSummary(e.step, "", "", None, None, e.source)
                steps.append(s)
            s.outcome, s.detail = step_outcome(e.message)
            s.t_end_s = e.t_s
    for s in open_steps.values():
        s.outcome = "running" if live else "interrupted"
    return steps


def step_outcome(message: str) -> tuple[str, str]:
    """``(outcome, detail)`` of a ``step_end`` message ``outcome`` or ``outcome: detail``; an empty
    outcome reads ``done``."""
    outcome, _, detail = message.partition(":")
    return outcome.strip() or "done", detail.strip()


def format_run_time(seconds: float | None) -> str:
    """``h:mm:ss`` of a run time or duration (s); ``-`` when unknown."""
    if seconds is None or not np.isfinite(seconds) or seconds < 0:
        return "-"
    s = int(seconds)
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


def _iso(unix: float) -> str:
    try:
        return datetime.fromtimestamp(unix, timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
    except (OverflowError, OSError, ValueError):
        return f"{unix!r} (Unix time)"


# ---- rendering ----------------------------------------------------------------------------------
def render_summary(summary: RunSummary, console: Console, max_events: int = 40, traffic: bool = False) -> None:
    """Print the run as ``bench inspect`` does (:func:`bench.inspect_view.render_summary`, where the
    terminal view of a run lives)."""
    from bench.inspect_view import render_summary as render

    render(summary, console, max_events=max_events, traffic=traffic)
