"""Stream datasets of a run file: declaring a stream (``/streams/<key>`` with a ``time`` dataset and
one chunked dataset per column), checking and buffering appended rows in memory, writing them out
at a flush (one resize and one write per column), and the row counts written at close.

Units: ``time`` in s of run time; nominal rates in Hz; sizes in bytes.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property

import h5py
import numpy as np

from bench.record import layout
from bench.record.space import chunk_bytes, new_chunks

DEFAULT_CHUNK_ROWS = 4096
"""Rows per chunk when a stream declares no nominal rate."""
CHUNK_SPAN_S = 2.0
"""Run time (s) of data per chunk at the nominal rate."""
MAX_CHUNK_BYTES = 1024 * 1024
"""Largest chunk (bytes): stays inside HDF5's default 1 MiB chunk cache per dataset."""
MIN_CHUNK_ROWS = 64
BUFFER_SPILL_BYTES = 16 * 1024 * 1024
"""A stream's buffer is written out early past this size (bytes)."""
TIME_DESCRIPTION = "run time of each row (s since the start of the run)"


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


def check_name(name: str, what: str) -> None:
    """Refuse an empty name, or one that is not a single HDF5 path component."""
    if not isinstance(name, str) or not name or "/" in name or name in (".", "..") or "\x00" in name:
        raise ValueError(f"{what} {name!r} must be a non-empty name without '/'")


def check_stream(f: h5py.File, declared: dict[str, "StreamTable"], instrument: str, columns: list[Column],
                 stream: str) -> tuple[str, dict[str, np.dtype]]:
    """Check a stream declaration against the file ``f`` and the streams ``declared`` so far.

    Returns the stream key and the numpy dtype of every column; raises ``ValueError`` naming the
    problem (bad names, repeated or reserved columns, non-numeric dtypes, bad row shapes, a stream
    where an instrument's only stream is, or the reverse).
    """
    check_name(instrument, "instrument name")
    if stream:
        check_name(stream, "stream name")
    key = layout.stream_key(instrument, stream)
    if key in declared:
        raise ValueError(f"stream {key!r} was already added")
    if not columns:
        raise ValueError(f"stream {key!r} needs at least one column")
    dtypes: dict[str, np.dtype] = {}
    for c in columns:
        check_name(c.name, f"column name of stream {key!r}")
        if c.name == layout.TIME:
            raise ValueError(f"stream {key!r}: column name {layout.TIME!r} is reserved for the run time of each row")
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
    parent = layout.stream_path(instrument)
    if not stream and parent in f:
        raise ValueError(f"stream {key!r} cannot be added: {layout.absolute(parent)} already holds other streams")
    if stream and instrument in declared:
        raise ValueError(f"stream {key!r} cannot be added: {layout.absolute(parent)} is already a stream")
    return key, dtypes


def chunk_rows(c: Column, rate_hz: float | None) -> int:
    """Rows per chunk of column ``c``: :data:`CHUNK_SPAN_S` of data at the nominal ``rate_hz`` (Hz),
    else :data:`DEFAULT_CHUNK_ROWS`, within :data:`MIN_CHUNK_ROWS` and :data:`MAX_CHUNK_BYTES`."""
    item = np.dtype(c.dtype).itemsize * int(np.prod(c.shape, dtype=np.int64))
    rows = DEFAULT_CHUNK_ROWS if rate_hz is None or not rate_hz > 0 else int(round(CHUNK_SPAN_S * rate_hz))
    return max(MIN_CHUNK_ROWS, min(rows, MAX_CHUNK_BYTES // max(item, 1)))


def _new_column(g: h5py.Group, c: Column, rate_hz: float | None) -> h5py.Dataset:
    shape = tuple(int(s) for s in c.shape)
    chunks = (chunk_rows(c, rate_hz), *shape)
    # chunk cache of two chunks: the file's default (1 MiB a dataset) keeps every finished chunk of a
    # slow stream (512-byte chunks of a 1-Hz monitor column: 36 h of them), so memory grew with run length
    cache = 2 * int(np.prod(chunks, dtype=np.int64)) * np.dtype(c.dtype).itemsize
    ds = g.create_dataset(c.name, shape=(0, *shape), maxshape=(None, *shape), dtype=c.dtype, chunks=chunks,
                          fletcher32=True, rdcc_nbytes=cache)  # checked on every read: bench/record/verify.py
    ds.attrs[layout.ATTR_UNITS] = c.units
    return ds


def convert(a: np.ndarray, dt: np.dtype, key: str, name: str) -> np.ndarray:
    """Copy ``a`` as dtype ``dt``, refusing lossy kinds of conversion (``ValueError``)."""
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


def _number(v: object, key: str, name: str) -> float:
    """``v`` as a float for a float column; ``ValueError`` for what is not a real number (as
    :func:`convert`: text, complex, None)."""
    if v.__class__ is float:
        return v  # type: ignore[return-value]
    if isinstance(v, (bool, int, np.integer, np.floating)) or (isinstance(v, np.ndarray) and v.shape == () and v.dtype.kind in "biuf"):
        return float(v)  # type: ignore[arg-type]
    raise ValueError(f"stream {key!r}: column {name!r} has a value of type {type(v).__name__}, expected a number")


@dataclass
class StreamTable:
    """One declared stream: its group and datasets (``time`` first, then the columns), the rows
    buffered for the next flush, and how many rows were accepted and written."""

    key: str
    group: h5py.Group
    columns: list[Column]
    dtypes: dict[str, np.dtype]
    datasets: dict[str, h5py.Dataset]
    pending: dict[str, list[np.ndarray]]
    row_bytes: int
    chunk_rows: dict[str, int] = field(default_factory=dict)  # per dataset
    chunk_bytes: dict[str, int] = field(default_factory=dict)
    pending_rows: int = 0
    pending_bytes: int = 0
    on_disk: int = 0  # rows written to the datasets
    appended: int = 0  # rows accepted by the recorder
    _need: tuple[int, int, int] = (0, 0, 0)  # (on_disk, pending_rows, need_bytes) of the last need_bytes()
    row_values: list[list[float]] = field(default_factory=list)
    """Rows given one at a time (:meth:`push_row`: time then every column, as Python floats), made
    into arrays before the next batch, write or discard."""

    @classmethod
    def create(cls, f: h5py.File, key: str, columns: list[Column], dtypes: dict[str, np.dtype],
               rate_hz: float | None) -> "StreamTable":
        """Create the group and datasets of a stream checked by :func:`check_stream` (before SWMR mode)."""
        instrument, stream = layout.split_stream_key(key)
        g = f.require_group(layout.stream_path(instrument))
        if stream:
            g = g.create_group(stream)
        g.attrs[layout.ATTR_INSTRUMENT] = instrument
        g.attrs[layout.ATTR_STREAM] = stream
        g.attrs[layout.ATTR_COLUMNS] = layout.COLUMN_SEPARATOR.join([layout.TIME] + [c.name for c in columns])
        if rate_hz is not None:
            g.attrs[layout.ATTR_RATE_HZ_NOMINAL] = float(rate_hz)
        datasets = {layout.TIME: _new_column(g, Column(layout.TIME, layout.TIME_UNITS, "f8"), rate_hz)}
        datasets[layout.TIME].attrs[layout.ATTR_DESCRIPTION] = TIME_DESCRIPTION
        for c in columns:
            datasets[c.name] = _new_column(g, c, rate_hz)
        all_dtypes = {layout.TIME: np.dtype("f8"), **dtypes}
        row_bytes = sum(all_dtypes[n].itemsize * int(np.prod(ds.shape[1:], dtype=np.int64)) for n, ds in datasets.items())
        return cls(
            key, g, list(columns), all_dtypes, datasets, {n: [] for n in datasets}, row_bytes,
            chunk_rows={n: int(ds.chunks[0]) for n, ds in datasets.items()},
            chunk_bytes={n: chunk_bytes(ds) for n, ds in datasets.items()},
        )

    def prepare(self, time_s: np.ndarray, columns: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Check a batch (``time_s`` (n,) run times in s, every column (n, *shape)) and convert it
        to the stored dtypes; ``ValueError`` names what is wrong."""
        t = np.asarray(time_s)
        if t.ndim != 1:
            raise ValueError(f"stream {self.key!r}: time_s must be one-dimensional (n,), got shape {t.shape}")
        n = t.shape[0]
        names = [c.name for c in self.columns]
        missing = [c for c in names if c not in columns]
        extra = [c for c in columns if c not in self.dtypes or c == layout.TIME]
        if missing or extra:
            parts = []
            if missing:
                parts.append(f"missing column(s) {', '.join(missing)}")
            if extra:
                parts.append(f"unknown column(s) {', '.join(extra)}")
            raise ValueError(f"stream {self.key!r}: {'; '.join(parts)} (columns: {', '.join(names)})")
        batch = {layout.TIME: convert(t, np.dtype("f8"), self.key, layout.TIME)}
        for c in self.columns:
            a = np.asarray(columns[c.name])
            want = (n, *c.shape)
            if a.shape != want:
                raise ValueError(f"stream {self.key!r}: column {c.name!r} has shape {a.shape}, expected {want}")
            batch[c.name] = convert(a, self.dtypes[c.name], self.key, c.name)
        return batch

    @cached_property
    def takes_rows(self) -> bool:
        """Whether :meth:`push_row` takes rows of this stream: every column a scalar float."""
        return all(not c.shape and self.dtypes[c.name].kind == "f" for c in self.columns)

    def push_row(self, t_s: float, values: Mapping[str, float]) -> None:
        """Buffer one row (run time ``t_s`` in s, a number for every column, float columns only:
        :attr:`takes_rows`) without making arrays of it; ``ValueError`` as :meth:`prepare`."""
        if len(values) != len(self.columns) or not all(c.name in values for c in self.columns):
            self.prepare(np.array([t_s]), {k: np.array([v]) for k, v in values.items()})  # says what is wrong
        row = [_number(t_s, self.key, layout.TIME)]
        for c in self.columns:
            row.append(_number(values[c.name], self.key, c.name))
        self.row_values.append(row)
        self.pending_rows += 1
        self.pending_bytes += self.row_bytes

    def pop_row(self) -> None:
        """Take back the row :meth:`push_row` buffered last."""
        self.row_values.pop()
        self.pending_rows -= 1
        self.pending_bytes -= self.row_bytes

    def _rows_to_arrays(self) -> None:
        """The rows :meth:`push_row` buffered, as one array per dataset at the end of ``pending``."""
        if not self.row_values:
            return
        a = np.array(self.row_values, dtype=np.float64)
        for i, name in enumerate(self.datasets):
            self.pending[name].append(np.ascontiguousarray(a[:, i], dtype=self.dtypes[name]))
        self.row_values.clear()

    def push(self, batch: dict[str, np.ndarray]) -> int:
        """Buffer a prepared batch for the next flush; returns its rows."""
        self._rows_to_arrays()
        n = batch[layout.TIME].shape[0]
        for name, a in batch.items():
            self.pending[name].append(a)
        self.pending_rows += n
        self.pending_bytes += n * self.row_bytes
        return n

    def pop(self, batch: dict[str, np.ndarray]) -> None:
        """Take back the batch :meth:`push` buffered last."""
        n = batch[layout.TIME].shape[0]
        for name in batch:
            self.pending[name].pop()
        self.pending_rows -= n
        self.pending_bytes -= n * self.row_bytes

    def need_bytes(self) -> int:
        """Bytes of new chunks writing the buffered rows allocates."""
        if not self.pending_rows:
            return 0
        on_disk, rows, need = self._need
        if (on_disk, rows) != (self.on_disk, self.pending_rows):  # the recorder asks at every append of any stream
            need = sum(new_chunks(self.chunk_rows[name], self.on_disk, self.pending_rows) * self.chunk_bytes[name]
                       for name in self.datasets)
            self._need = (self.on_disk, self.pending_rows, need)
        return need

    def write(self) -> None:
        """Extend every dataset by the buffered rows and write them (one resize and write per column)."""
        n = self.pending_rows
        if n == 0:
            return
        self._rows_to_arrays()
        new = self.on_disk + n
        for name, ds in self.datasets.items():
            parts = self.pending[name]
            a = parts[0] if len(parts) == 1 else np.concatenate(parts)
            ds.resize(new, axis=0)
            ds[self.on_disk:new] = a
            parts.clear()
        self.on_disk = new
        self.pending_rows = 0
        self.pending_bytes = 0

    def discard(self) -> None:
        """Drop the buffered rows (after a refused flush whose rows did not fit)."""
        for parts in self.pending.values():
            parts.clear()
        self.row_values.clear()
        self.pending_rows = self.pending_bytes = 0

    def finalise(self, f: h5py.File) -> int:
        """Write the row counts to the stream's group in the reopened (non-SWMR) file ``f``;
        returns the rows present in every column."""
        g = f[layout.stream_path(self.key)]
        rows = min(int(g[name].shape[0]) for name in self.datasets)
        g.attrs[layout.ATTR_ROWS] = np.int64(rows)
        g.attrs[layout.ATTR_ROWS_APPENDED] = np.int64(self.appended)
        return rows

    def handles(self) -> list[object]:
        """The HDF5 objects this stream holds (kept alive after a failed write)."""
        return [self.group, *self.datasets.values()]
