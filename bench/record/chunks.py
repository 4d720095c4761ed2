"""Reading a run file's chunked datasets past damaged chunks (one home for data checksums).

Every chunk of a stream and of the event log carries HDF5's Fletcher-32 checksum, which HDF5 checks
on every read: reading a chunk whose bytes changed on disk raises ``OSError`` ("filter returned
failure during read"). :func:`find_damage` reads a dataset in blocks and, when a block fails, chunk
by chunk, listing the chunks that fail (:class:`BadChunk`).

Fletcher-32 of all-zero bytes is zero, so a chunk zeroed on disk together with its checksum passes.
Such chunks are found too (reason :data:`ZEROED`): a ``time`` chunk that is all zero (run times
increase, so at most one row can be 0 s), and an all-zero chunk lying in a run of zero bytes that
also covers part of a chunk of real data failing its checksum (:class:`ChunkMap`). A chunk of true
zero data next to undamaged chunks, or next to a chunk of zeros with a bit flipped, is left alone.

:func:`excluded_rows` turns the bad chunks of one stream's columns into the row ranges an analysis
leaves out (:class:`ExcludedRows`, with their run times); :func:`read_stream_rows` reads a stream's
columns without those rows.

Rows are 0-based, ranges half-open ``[start, end)``; run times in s; file offsets and sizes in bytes.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from bench.record import layout

CHECKSUM_FAILED = "checksum failed"
ZEROED = "zeroed on disk"
"""Reason of an all-zero chunk taken as damage (its Fletcher-32 checksum, zero too, cannot tell)."""
READ_BLOCK_BYTES = 64 * 1024 * 1024
"""Largest block (bytes) :func:`find_damage` reads at once when it does not keep the rows."""
_SCAN_BYTES = 1024 * 1024
"""Bytes read at a time while following a run of zero bytes through the file."""
_FILTER_FAILED = "filter returned failure"


@dataclass(frozen=True)
class BadChunk:
    """One chunk of dataset ``dataset`` (HDF5 path) that cannot be trusted: its rows
    ``[row_start, row_end)`` (within the rows read) and ``reason`` (:data:`CHECKSUM_FAILED`, :data:`ZEROED`)."""

    dataset: str
    row_start: int
    row_end: int
    reason: str

    @property
    def column(self) -> str:
        """The dataset's name in its group (the stream column: ``gyro``, ``time``)."""
        return self.dataset.rsplit("/", 1)[-1]


@dataclass(frozen=True)
class ExcludedRows:
    """Rows ``[row_start, row_end)`` of stream ``stream`` left out because a chunk of one of its
    columns is damaged (``reason``, e.g. ``checksum failed (gyro)``). Run times (s): of the first and
    last excluded row when the ``time`` column is intact there (``t_start_s``, ``t_end_s``), and of
    the good rows either side (``t_before_s``, ``t_after_s``); None where there is none."""

    stream: str
    row_start: int
    row_end: int
    reason: str
    t_start_s: float | None = None
    t_end_s: float | None = None
    t_before_s: float | None = None
    t_after_s: float | None = None

    @property
    def rows(self) -> int:
        return self.row_end - self.row_start

    def time_text(self) -> str:
        """``t 40.96–81.91 s``; ``t between 40.95 and 81.92 s`` when the times themselves are damaged;
        ``""`` when no run time is known (a dataset without times)."""
        if self.t_start_s is not None and self.t_end_s is not None:
            return f"t {self.t_start_s:.2f}–{self.t_end_s:.2f} s"
        if self.t_before_s is None and self.t_after_s is None:
            return ""
        before = "the start" if self.t_before_s is None else f"{self.t_before_s:.2f}"
        after = "the end" if self.t_after_s is None else f"{self.t_after_s:.2f} s"
        return f"t between {before} and {after}"

    def rows_text(self, what: str = "rows") -> str:
        """``rows 4096–8191 (t 40.96–81.91 s)``."""
        t = self.time_text()
        return f"{what} {self.row_start}–{self.row_end - 1}" + (f" ({t})" if t else "")

    def damage_text(self) -> str:
        """``rows 4096–8191 of stream acs_board (t 40.96–81.91 s): checksum failed (gyro)``."""
        t = self.time_text()
        return f"rows {self.row_start}–{self.row_end - 1} of stream {self.stream}" + (f" ({t})" if t else "") + f": {self.reason}"

    def describe(self) -> str:
        """``excluded rows 4096–8191 of stream acs_board (t 40.96–81.91 s): checksum failed (gyro)``."""
        return f"excluded {self.damage_text()}"

    def json(self) -> dict[str, object]:
        return {"stream": self.stream, "row_start": self.row_start, "row_end": self.row_end, "rows": self.rows,
                "t_start_s": self.t_start_s, "t_end_s": self.t_end_s, "t_before_s": self.t_before_s,
                "t_after_s": self.t_after_s, "reason": self.reason}


@dataclass
class StreamRows:
    """Columns of one stream (name -> rows) with the damaged rows left out, and which rows those were."""

    data: dict[str, np.ndarray]
    excluded: list[ExcludedRows] = field(default_factory=list)


def has_checksum(ds: h5py.Dataset) -> bool:
    """Whether ``ds`` is chunked with the Fletcher-32 filter (files written before checksums are not)."""
    try:
        return ds.chunks is not None and bool(ds.fletcher32)
    except Exception:  # noqa: BLE001 - a damaged creation property list: no checksum we can rely on
        return False


def is_checksum_failure(exc: BaseException) -> bool:
    """Whether ``exc`` is HDF5 refusing a chunk whose Fletcher-32 checksum fails."""
    return isinstance(exc, OSError) and _FILTER_FAILED in str(exc)


def _failure(exc: OSError) -> str:
    """The reason of a failed chunk read; a failure other than a checksum (damaged metadata) is raised."""
    if is_checksum_failure(exc):
        return CHECKSUM_FAILED
    raise exc


def read_rows(ds: h5py.Dataset, start: int, end: int, *, torn_tail: bool = False) -> tuple[np.ndarray, list[BadChunk]]:
    """Rows ``[start, end)`` of ``ds`` (``start`` at a chunk boundary) and the chunks among them that
    fail their checksum, whose rows are zeros in the array. Other read failures (damaged metadata)
    raise ``OSError``: reading further would only fail again, each time slowly.

    ``torn_tail``: the file was not finalised (its writer stopped, or still writes). Its recorder
    rewrites the last, partial chunk of a dataset in place at every flush, and a writer killed in the
    middle of that rewrite leaves the chunk's checksum wrong although its rows already flushed hold
    the same bytes as before: that chunk is then read past its checksum (:func:`_raw_rows`), not left
    out. ``bench inspect --verify`` still reports it (it never passes ``torn_tail``)."""
    try:
        return np.asarray(ds[start:end]), []
    except OSError as exc:
        _failure(exc)
        if ds.chunks is None:
            raise
    out = np.zeros((end - start, *ds.shape[1:]), dtype=ds.dtype)
    bad = []
    step = int(ds.chunks[0])
    for a in range(start, end, step):
        b = min(a + step, end)
        try:
            out[a - start:b - start] = ds[a:b]
        except OSError as exc:
            reason = _failure(exc)
            raw = _raw_rows(ds, a, b) if torn_tail and a + step >= int(ds.shape[0]) else None
            if raw is not None:
                out[a - start:b - start] = raw
                continue
            bad.append(BadChunk(ds.name, a, b, reason))
    return out, bad


def _raw_rows(ds: h5py.Dataset, a: int, b: int) -> np.ndarray | None:
    """Rows ``[a, b)`` of the chunk starting at row ``a`` read past its checksum: the stored bytes
    without their trailing 4-byte Fletcher-32. None where that cannot be done safely (another filter
    on the dataset, a chunk not spanning whole rows, a short chunk)."""
    try:
        if ds.compression is not None or ds.shuffle or ds.scaleoffset is not None or tuple(ds.chunks[1:]) != tuple(ds.shape[1:]):
            return None
        _mask, raw = ds.id.read_direct_chunk((a,) + (0,) * (ds.ndim - 1))
        n = int(np.prod(ds.chunks, dtype=np.int64)) * ds.dtype.itemsize
        if len(raw) < n:
            return None
        return np.frombuffer(raw[:n], dtype=ds.dtype).reshape(ds.chunks)[: b - a].copy()
    except Exception:  # noqa: BLE001 - h5py's low level raises many types on a damaged chunk index
        return None


def zero_chunks(a: np.ndarray, step: int) -> list[int]:
    """Offsets (rows from the start of ``a``, multiples of ``step``) of the chunks of ``step`` rows
    whose every byte is zero."""
    n = int(a.shape[0])
    if n == 0:
        return []
    flat = np.ascontiguousarray(a).reshape(-1).view(np.uint8)
    per = flat.size // n * step  # bytes per chunk
    full = n // step
    out = [int(i) * step for i in np.flatnonzero(~flat[:full * per].reshape(full, per).any(axis=1))] if full else []
    if n % step and not flat[full * per:].any():
        out.append(full * step)
    return out


class ChunkMap:
    """Where every chunk of every chunked dataset of open file ``f`` (at ``path``) lies, built on first
    use, to tell a chunk zeroed on disk from one of true zero data."""

    def __init__(self, f: h5py.File, path: Path):
        self._f = f
        self._path = Path(path)
        self._extents: list[tuple[int, int, str, int]] | None = None  # (offset, size, dataset, first row)
        self._offsets: list[int] = []
        self._runs: list[tuple[int, int, bool]] = []  # zero runs seen: (start, end, damage)
        self._fails: dict[tuple[str, int], bool] = {}  # (dataset, first row) -> zeroed in part

    def _build(self) -> list[tuple[int, int, str, int]]:
        if self._extents is None:
            extents: list[tuple[int, int, str, int]] = []

            def visit(_name: str, obj: object) -> None:
                if not isinstance(obj, h5py.Dataset) or obj.chunks is None:
                    return

                def add(info: Any) -> None:
                    if info.byte_offset is not None and info.size:
                        extents.append((int(info.byte_offset), int(info.size), obj.name, int(info.chunk_offset[0])))

                if hasattr(obj.id, "chunk_iter"):  # one pass (get_chunk_info(i) walks the index: n² in all)
                    obj.id.chunk_iter(add)
                else:
                    for i in range(obj.id.get_num_chunks()):
                        add(obj.id.get_chunk_info(i))

            self._f.visititems(visit)
            extents.sort()
            self._extents, self._offsets = extents, [e[0] for e in extents]
        return self._extents

    def _containing(self, offset: int) -> tuple[int, int, str, int] | None:
        extents = self._build()
        i = bisect.bisect_right(self._offsets, offset) - 1
        if i >= 0 and extents[i][0] <= offset < extents[i][0] + extents[i][1]:
            return extents[i]
        return None

    def _zeroed_in_part(self, extent: tuple[int, int, str, int]) -> bool:
        """Whether the chunk at ``extent``, which a run of zero bytes covers in part, fails its
        checksum while holding real data (more than one non-zero byte: a bit flipped in a chunk of
        true zeros is no sign of a zeroed region around it)."""
        offset, size, dataset, row = extent
        key = (dataset, row)
        if key not in self._fails:
            ds = self._f[dataset]
            end = min(row + int(ds.chunks[0]), int(ds.shape[0]))
            try:
                if end > row:
                    ds[row:end]
                self._fails[key] = False
            except OSError as exc:
                if not is_checksum_failure(exc):
                    raise
                with open(self._path, "rb") as fh:
                    fh.seek(offset)
                    self._fails[key] = np.count_nonzero(np.frombuffer(fh.read(size), dtype=np.uint8)) > 1
        return self._fails[key]

    def zeroed(self, ds: h5py.Dataset, row: int, *, times: bool = False) -> bool:
        """Whether the chunk of ``ds`` starting at ``row``, whose rows read as zeros, was zeroed on
        disk: it is stored (not a chunk a live writer has not written yet, which reads as fill
        values), all its bytes are zero, and it holds run times (``times``) or lies in a run of zero
        bytes of the file that reaches into a chunk of real data failing its checksum."""
        try:
            info = ds.id.get_chunk_info_by_coord((row,) + (0,) * (ds.ndim - 1))
        except Exception:  # noqa: BLE001 - no such chunk (not written: fill values)
            return False
        if info.byte_offset is None or not info.size:
            return False
        offset, size = int(info.byte_offset), int(info.size)
        for start, end, damage in self._runs:
            if start <= offset and offset + size <= end:
                return damage or times
        run = _zero_run(self._path, offset, size)
        if run is None:
            return False
        if times:
            return True
        start, end = run
        damage = False
        for edge in (start, end):  # the chunk holding the run's first byte / the first byte after it
            e = self._containing(edge)
            if e is not None and e[0] < edge and self._zeroed_in_part(e):
                damage = True
        self._runs.append((start, end, damage))
        return damage


def _zero_run(path: Path, offset: int, size: int) -> tuple[int, int] | None:
    """The run of zero bytes of the file holding ``[offset, offset + size)``, as ``(start, end)``;
    None if those bytes are not all zero."""
    with open(path, "rb") as fh:
        fh.seek(offset)
        stored = np.frombuffer(fh.read(size), dtype=np.uint8)
        if stored.size < size or stored.any():
            return None
        start = offset
        while start > 0:
            n = min(_SCAN_BYTES, start)
            fh.seek(start - n)
            nz = np.flatnonzero(np.frombuffer(fh.read(n), dtype=np.uint8))
            if nz.size:
                start = start - n + int(nz[-1]) + 1
                break
            start -= n
        end = offset + size
        fh.seek(end)
        while True:
            block = fh.read(_SCAN_BYTES)
            if not block:
                break
            nz = np.flatnonzero(np.frombuffer(block, dtype=np.uint8))
            if nz.size:
                end += int(nz[0])
                break
            end += len(block)
    return start, end


def find_damage(ds: h5py.Dataset, rows: int, chunks: ChunkMap, *, is_time: bool = False,
                keep: bool = False, torn_tail: bool = False) -> tuple[np.ndarray | None, list[BadChunk]]:
    """Check every chunk of the first ``rows`` rows of ``ds``: those failing their checksum and those
    zeroed on disk (:meth:`ChunkMap.zeroed`; ``is_time``: ``ds`` holds run times, so a stored
    all-zero chunk is zeroed unless it is one row at 0 s). Returns the rows (``keep``; bad rows read as zeros, else
    None) and the bad chunks in row order. Blocks of at most :data:`READ_BLOCK_BYTES` are read at a
    time when the rows are not kept. ``torn_tail``: as :func:`read_rows`."""
    step = int(ds.chunks[0]) if ds.chunks is not None else max(rows, 1)
    row_bytes = max(ds.dtype.itemsize * int(np.prod(ds.shape[1:], dtype=np.int64)), 1)
    block = rows if keep else max(step, READ_BLOCK_BYTES // row_bytes // step * step)
    parts: list[np.ndarray] = []
    bad: list[BadChunk] = []
    for start in range(0, rows, max(block, 1)):
        end = min(start + block, rows)
        a, failed = read_rows(ds, start, end, torn_tail=torn_tail)
        bad += failed
        if ds.chunks is not None and (is_time or has_checksum(ds)):
            failed_rows = {b.row_start for b in failed}
            for off in zero_chunks(a, step):
                row = start + off
                if row in failed_rows:
                    continue
                n = min(step, end - row)
                if is_time and row == 0 and n == 1:
                    continue  # one row at run time 0 s
                if chunks.zeroed(ds, row, times=is_time):
                    bad.append(BadChunk(ds.name, row, row + n, ZEROED))
        if keep:
            parts.append(a)
    bad.sort(key=lambda b: b.row_start)
    if not keep:
        return None, bad
    return (parts[0] if len(parts) == 1 else np.concatenate(parts)) if parts else np.asarray(ds[0:0]), bad


def excluded_rows(stream: str, bad: list[BadChunk], t: np.ndarray | None, time_column: str = layout.TIME) -> list[ExcludedRows]:
    """The row ranges of stream ``stream`` covered by the bad chunks of its columns, merged where
    they touch, with their reasons and run times (``t``: the run times in s of every row, read from
    column ``time_column``, damaged rows included: where that column is damaged the times of the
    good rows either side are given)."""
    merged: list[tuple[int, int, list[BadChunk]]] = []
    for b in sorted(bad, key=lambda b: (b.row_start, b.row_end)):
        if merged and b.row_start <= merged[-1][1]:
            a, z, group = merged[-1]
            merged[-1] = (a, max(z, b.row_end), group + [b])
        else:
            merged.append((b.row_start, b.row_end, [b]))
    n = 0 if t is None else int(t.shape[0])
    t_ok = np.ones(n, dtype=bool)
    for b in bad:
        if b.column == time_column:
            t_ok[b.row_start:b.row_end] = False

    def time_at(i: int) -> float | None:
        return float(t[i]) if t is not None and 0 <= i < n and t_ok[i] else None

    out = []
    for a, z, group in merged:
        by_reason: dict[str, list[str]] = {}
        for b in group:
            cols = by_reason.setdefault(b.reason, [])
            if b.column not in cols:
                cols.append(b.column)
        reason = "; ".join(f"{r} ({', '.join(cols)})" for r, cols in by_reason.items())
        out.append(ExcludedRows(stream, a, z, reason, time_at(a), time_at(z - 1), time_at(a - 1), time_at(z)))
    return out


def read_stream_rows(f: h5py.File, path: Path, stream: str, datasets: dict[str, h5py.Dataset], rows: int) -> StreamRows:
    """The first ``rows`` rows of the columns ``datasets`` (name -> dataset; ``time`` among them) of
    stream ``stream`` in open run file ``f`` at ``path``, without the rows of damaged chunks
    (:func:`find_damage`), which are listed in :attr:`StreamRows.excluded`. In a file not finalised
    (status ``running``: crashed or still written) the last chunk of each column is read past a
    failing checksum (``torn_tail`` of :func:`read_rows`)."""
    chunks = ChunkMap(f, path)
    status = f.attrs.get(layout.ATTR_STATUS, "")
    torn_tail = (status.decode("utf-8", "replace") if isinstance(status, bytes) else str(status)) == layout.STATUS_RUNNING
    data: dict[str, np.ndarray] = {}
    bad: list[BadChunk] = []
    for name, ds in datasets.items():
        a, found = find_damage(ds, rows, chunks, is_time=name == layout.TIME, keep=True, torn_tail=torn_tail)
        data[name] = a
        bad += found
    if not bad:
        return StreamRows(data)
    excluded = excluded_rows(stream, bad, data.get(layout.TIME))
    keep = np.ones(rows, dtype=bool)
    for e in excluded:
        keep[e.row_start:e.row_end] = False
    return StreamRows({n: a[keep] for n, a in data.items()}, excluded)


def checksum_state(datasets: list[h5py.Dataset]) -> str:
    """``all`` when every one of ``datasets`` has a Fletcher-32 checksum, ``none`` when none has
    (a file written before checksums), else ``some``."""
    have = [has_checksum(ds) for ds in datasets]
    return "all" if have and all(have) else ("some" if any(have) else "none")
