"""The end of a run file's SWMR life: finalising the status, and what to do when HDF5 failed.

In SWMR mode HDF5 cannot modify attributes, so :func:`finalise_status` reopens the released file
normally (``"r+"``, waiting for readers' short file locks) and writes the row counts, ``ended_utc``,
``abort_reason`` and ``status``. After a failed HDF5 write the file cannot be closed at all
(:func:`keep_alive`). Times in s.
"""

from __future__ import annotations

import ctypes
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Iterable

import h5py
import numpy as np

from bench.record import layout
from bench.record.digest import write_digest
from bench.redact import redact
from bench.record.streams import StreamTable

LOCK_RETRY_S = 5.0
"""How long closing waits for readers (``bench watch``, ``bench inspect``) to let go of the file (s)."""
LOCK_POLL_S = 0.02
"""Pause (s) between attempts to reopen a file a reader holds."""


def open_for_status(path: Path) -> h5py.File:
    """Reopen a released run file read-write. A reader holds a shared HDF5 file lock for the
    milliseconds of a read; retry while it does, up to :data:`LOCK_RETRY_S`."""
    deadline = time.monotonic() + LOCK_RETRY_S
    while True:
        try:
            return h5py.File(path, "r+", libver="latest")
        except OSError as exc:
            if "unable to lock file" not in str(exc) or time.monotonic() >= deadline:
                raise
            time.sleep(LOCK_POLL_S)


def finalise_status(path: Path, streams: Iterable[StreamTable], status: str, abort_reason: str) -> None:
    """Write the final root attributes and every stream's row counts into the released file at
    ``path``. h5py/OS errors propagate."""
    with open_for_status(path) as f:
        total = sum(st.finalise(f) for st in streams)
        f.attrs[layout.ATTR_ROWS_TOTAL] = np.int64(total)
        f.attrs[layout.ATTR_ENDED_UTC] = layout.utc_text(datetime.now(timezone.utc))
        f.attrs[layout.ATTR_ABORT_REASON] = redact(str(abort_reason))
        f.attrs[layout.ATTR_STATUS] = status
        write_digest(f)


def keep_alive(objs: Iterable[object]) -> None:
    """Keep every HDF5 handle of a file whose write failed alive until the process ends.

    After a failed write HDF5 2.0 (h5py 3.16) crashes the process with a segmentation fault
    (use after free in ``H5D__flush_all_cb``) when the file is closed, or when its objects are
    garbage-collected, at the latest at interpreter exit. Holding one extra reference on each
    object means they are never closed: the OS closes the descriptor at exit, and the file keeps
    what the last successful flush wrote (readable as SWMR, reported as crashed).
    """
    for obj in objs:
        if obj is not None:
            ctypes.pythonapi.Py_IncRef(ctypes.py_object(obj))
