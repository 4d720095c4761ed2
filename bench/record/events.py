"""The event log of a run file: ``/events`` (one fixed-size row per event, :data:`layout.EVENT_DTYPE`)
and ``/events_blob`` (the messages and data bytes the rows point into).

Events are buffered in memory and appended to both datasets at a flush (one resize and one write
each). Times: ``t_s`` run time (s), ``wall_unix`` wall time (s since the Unix epoch); sizes in bytes.
"""

from __future__ import annotations

import time

import h5py
import numpy as np

from bench.record import layout
from bench.record.space import new_chunks
from bench.redact import redact, redact_bytes

EVENT_CHUNK_ROWS = 1024
"""Rows per chunk of ``/events``."""
BLOB_CHUNK_BYTES = 64 * 1024
"""Bytes per chunk of ``/events_blob``."""

EVENTS_UNITS = "t_s: s (run time); wall_unix: s (Unix time); msg_off, data_off, *_len: bytes in /events_blob"
BLOB_UNITS = "bytes (utf-8 messages and raw event data)"


def create_event_datasets(f: h5py.File) -> None:
    """Create the empty, resizable ``/events`` and ``/events_blob`` (before SWMR mode)."""
    ev = f.create_dataset(layout.EVENTS, shape=(0,), maxshape=(None,), dtype=layout.EVENT_DTYPE, chunks=(EVENT_CHUNK_ROWS,), fletcher32=True)
    ev.attrs[layout.ATTR_UNITS] = EVENTS_UNITS
    blob = f.create_dataset(layout.EVENTS_BLOB, shape=(0,), maxshape=(None,), dtype="u1", chunks=(BLOB_CHUNK_BYTES,), fletcher32=True)
    blob.attrs[layout.ATTR_UNITS] = BLOB_UNITS


def cut_utf8(text: str, limit: int) -> bytes:
    """``text`` as utf-8, cut to at most ``limit`` bytes without splitting a character."""
    raw = text.encode("utf-8", errors="replace")
    if len(raw) <= limit:
        return raw
    return raw[:limit].decode("utf-8", errors="ignore").encode("utf-8")


MAX_SOURCES_KEPT = 256
"""Encoded event sources kept for reuse (instrument and step names: a handful per run)."""


def _encode_kind(kind: str) -> bytes:
    """An event kind as stored: 1-16 ASCII characters, else ``ValueError``."""
    try:
        kind_b = kind.encode("ascii")
    except UnicodeEncodeError:
        raise ValueError(f"event kind {kind!r} must be ASCII") from None
    if not 0 < len(kind_b) <= layout.EVENT_KIND_BYTES:
        raise ValueError(f"event kind {kind!r} must be 1 to {layout.EVENT_KIND_BYTES} characters")
    return kind_b


class EventLog:
    """Buffered events of one open run file and the two datasets they go to."""

    def __init__(self, f: h5py.File):
        self.events_ds: h5py.Dataset = f[layout.EVENTS]
        self.blob_ds: h5py.Dataset = f[layout.EVENTS_BLOB]
        self._rows: list[tuple] = []
        self._blob_pending = bytearray()
        self._blob_total = 0  # bytes in the blob including pending (= offset of the next message)
        self._on_disk = 0  # event rows written
        self._kinds: dict[str, bytes] = {}
        self._sources: dict[str, bytes] = {}

    def add(self, kind: str, source: str, message: str, *, t_s: float, step: int, data: bytes) -> None:
        """Buffer one event (see :meth:`bench.record.RunRecorder.event`). Raises ``ValueError`` for a
        kind that is not 1-16 ASCII characters or a step outside int32. A run logs every command and
        reply (tens per second of run time): kinds and sources are encoded once and kept."""
        message = redact(message)  # no credential is stored (bench/redact.py)
        if data and kind not in layout.TRAFFIC_EVENT_KINDS:  # traffic is kept byte for byte: replay answers it
            data = redact_bytes(data)
        kind_b = self._kinds.get(kind)
        if kind_b is None:
            kind_b = self._kinds[kind] = _encode_kind(kind)
        source_b = self._sources.get(source)
        if source_b is None:
            source_b = cut_utf8(redact(source), layout.EVENT_SOURCE_BYTES)
            if len(self._sources) < MAX_SOURCES_KEPT:
                self._sources[source] = source_b
        if not -(2**31) <= step < 2**31:
            raise ValueError(f"event step {step} out of range")
        msg_b = message.encode("utf-8", errors="surrogateescape")
        msg_off = self._blob_total
        n_msg, n_data = len(msg_b), len(data)
        self._blob_pending += msg_b
        self._blob_pending += data
        self._blob_total = msg_off + n_msg + n_data
        self._rows.append((float(t_s), time.time(), kind_b, source_b, int(step), msg_off, n_msg, msg_off + n_msg, n_data))

    def need_bytes(self) -> int:
        """Bytes of new chunks writing the buffered events allocates."""
        need = new_chunks(EVENT_CHUNK_ROWS, self._on_disk, len(self._rows)) * EVENT_CHUNK_ROWS * layout.EVENT_DTYPE.itemsize
        blob_on_disk = self._blob_total - len(self._blob_pending)
        return need + new_chunks(BLOB_CHUNK_BYTES, blob_on_disk, len(self._blob_pending)) * BLOB_CHUNK_BYTES

    def write(self) -> None:
        """Append the buffered blob bytes, then the buffered rows (a reader never sees a row whose
        message is not there yet)."""
        if self._blob_pending:
            old = self.blob_ds.shape[0]
            add = np.frombuffer(bytes(self._blob_pending), dtype=np.uint8)
            self.blob_ds.resize(old + add.shape[0], axis=0)
            self.blob_ds[old:] = add
            self._blob_pending.clear()
        if self._rows:
            rows = np.array(self._rows, dtype=layout.EVENT_DTYPE)
            old = self._on_disk
            self.events_ds.resize(old + rows.shape[0], axis=0)
            self.events_ds[old:] = rows
            self._on_disk = old + rows.shape[0]
            self._rows.clear()

    def handles(self) -> list[object]:
        """The HDF5 objects this log holds (kept alive after a failed write)."""
        return [self.events_ds, self.blob_ds]
