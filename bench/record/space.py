"""Room for the next flush: how many bytes a flush allocates (HDF5 allocates whole chunks) and
whether they fit on the disk and under the file-size limit (``ulimit -f``).

HDF5 does not recover from a failed write, so the recorder asks here before every flush and
refuses it while the file is still consistent. Sizes in bytes.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Callable

import h5py
import numpy as np

from bench.record.reasons import mb

try:
    import resource
except ImportError:  # not on Windows
    resource = None  # type: ignore[assignment]

RESERVE_BYTES = 1024 * 1024
"""Kept free for metadata and finalising the status (bytes)."""


def chunk_bytes(ds: h5py.Dataset) -> int:
    """Size (bytes) of one chunk of ``ds``."""
    return int(np.prod(ds.chunks, dtype=np.int64)) * ds.dtype.itemsize


def new_chunks(chunk_rows: int, rows: int, add: int) -> int:
    """Chunks HDF5 allocates when ``add`` rows are appended to ``rows`` rows (chunks of ``chunk_rows``)."""
    if add <= 0:
        return 0
    return -(-(rows + add) // chunk_rows) - -(-rows // chunk_rows)


def space_problem(path: Path, need: int, free_bytes: Callable[[Path], int]) -> str:
    """Why ``need`` more bytes might not fit in the file at ``path``, or "".

    ``free_bytes(directory)`` gives the free space (bytes) of the file's directory (an ``OSError``
    there skips that check); the soft ``RLIMIT_FSIZE`` (``ulimit -f``) bounds the file's size.
    """
    try:
        free = free_bytes(path.parent)
    except OSError:
        free = None
    if free is not None and free < need:
        return f"disk nearly full: {mb(free)} free in {path.parent}, the next flush may need up to {mb(need)}"
    if resource is not None:
        soft = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
        if soft != resource.RLIM_INFINITY:
            try:
                size = os.path.getsize(path)
            except OSError:
                size = 0
            if size + need > soft:
                return (
                    f"file size limit (ulimit -f) of {mb(soft)} reached: the file has {mb(size)}, "
                    f"the next flush may need up to {mb(need)}"
                )
    return ""
