"""Room for the next flush: how many bytes a flush allocates (HDF5 allocates whole chunks) and
whether they fit on the disk and under the file-size limit (``ulimit -f``); and the space reserve
that lets a run file be finalised when another process has filled the disk.

HDF5 does not recover from a failed write, so the recorder asks here before every flush and
refuses it while the file is still consistent. Sizes in bytes.
"""

from __future__ import annotations

import errno
import os
import weakref
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

RESERVE_SUFFIX = ".reserve"
"""The reserve file of ``runs/X.h5`` is ``runs/.X.h5.reserve`` (hidden; never matches ``*.h5``)."""
_ZEROS = bytes(64 * 1024)


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


def reserve_path(run_path: Path) -> Path:
    """Where the space reserve of the run file at ``run_path`` lives: ``.<name>.reserve`` beside it."""
    return run_path.with_name(f".{run_path.name}{RESERVE_SUFFIX}")


STALE_RESERVE_AFTER_S = 60.0
"""A reserve whose run file has not been written for this long (s; a live recorder flushes at least
once a second, its heartbeat) was left by a killed run (SIGKILL, power loss)."""


def remove_stale_reserves(directory: Path, now_unix: float | None = None) -> list[Path]:
    """Delete the reserve files in ``directory`` left by killed runs: those whose run file is gone
    or was last written more than :data:`STALE_RESERVE_AFTER_S` ago. Returns what was deleted;
    never raises (a leftover costs disk space, nothing else)."""
    import time

    now = time.time() if now_unix is None else now_unix
    removed = []
    try:
        candidates = [p for p in Path(directory).iterdir() if p.name.startswith(".") and p.name.endswith(".h5" + RESERVE_SUFFIX)]
    except OSError:
        return removed
    for reserve in candidates:
        run_file = reserve.with_name(reserve.name[1:-len(RESERVE_SUFFIX)])
        try:
            if run_file.exists() and now - run_file.stat().st_mtime < STALE_RESERVE_AFTER_S:
                continue
            if reserve.is_symlink() or not reserve.is_file():
                continue  # not ours
            reserve.unlink()
            removed.append(reserve)
        except OSError:
            continue
    return removed


class SpaceReserve:
    """Disk space held for finalising a run file, as a file of allocated blocks beside it.

    A flush is refused while it and :data:`RESERVE_BYTES` might not fit, but another process can
    fill the disk between two flushes, and closing the file (the last rows, the events of the abort,
    HDF5's metadata, the final status) needs room. The recorder deletes the reserve right before
    those writes (:meth:`release`), so they have at least its size even on a full disk. It is also
    deleted when the recorder gives the file up, and at interpreter exit; only SIGKILL leaves it.
    """

    def __init__(self, path: Path):
        """Use :meth:`create`."""
        self.path = path
        self.size_bytes = 0
        self._finalizer = weakref.finalize(self, _unlink, path)

    @classmethod
    def create(cls, run_path: Path, size_bytes: int) -> "SpaceReserve":
        """Allocate ``size_bytes`` (bytes; capped at the file-size limit ``ulimit -f``) in a new
        reserve file beside ``run_path``. ``OSError`` (``ENOSPC`` …) if it cannot be allocated;
        then no reserve file is left."""
        remove_stale_reserves(run_path.parent)
        reserve = cls(reserve_path(run_path))
        # the run file was just created under a new name: a reserve there is a killed run's leftover
        fd = os.open(reserve.path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        os.close(fd)
        try:
            reserve.ensure(size_bytes)
        except BaseException:
            reserve.release()
            raise
        return reserve

    def ensure(self, size_bytes: int) -> None:
        """Grow the reserve to ``size_bytes`` (bytes, capped at ``ulimit -f``) of allocated blocks
        (``posix_fallocate``, else written zeros). ``OSError`` if the disk cannot give them; the
        reserve then keeps what it had. Does nothing once released."""
        size = min(int(size_bytes), _file_size_limit())
        if size <= self.size_bytes or not self._finalizer.alive:
            return
        fd = os.open(self.path, os.O_WRONLY)
        try:
            _allocate(fd, self.size_bytes, size)
        except BaseException:
            os.ftruncate(fd, self.size_bytes)  # give back what was added: the disk is full already
            raise
        finally:
            os.close(fd)
        self.size_bytes = size

    def release(self) -> int:
        """Delete the reserve file: its blocks are free for the writes that follow. Idempotent;
        returns the bytes given back (0 the second time)."""
        size, self.size_bytes = self.size_bytes, 0
        self._finalizer()
        return size

    @property
    def held(self) -> bool:
        """True until :meth:`release`."""
        return self._finalizer.alive


def _unlink(path: Path) -> None:
    try:
        os.unlink(path)
    except OSError:
        pass


def _allocate(fd: int, start: int, end: int) -> None:
    """Allocate bytes ``start``..``end`` of the file ``fd``: real blocks, not a sparse hole."""
    try:
        os.posix_fallocate(fd, start, end - start)
        return
    except AttributeError:  # not on this platform (macOS)
        pass
    except OSError as exc:
        if exc.errno not in (errno.EOPNOTSUPP, errno.EINVAL, errno.ENOSYS):
            raise
    os.lseek(fd, start, os.SEEK_SET)
    left = end - start
    while left > 0:
        left -= os.write(fd, _ZEROS[:min(left, len(_ZEROS))])
    os.fsync(fd)  # a file system that allocates at write-back (delayed allocation) does it now


def _file_size_limit() -> int:
    """The soft file-size limit (``ulimit -f``, bytes); a very large number when there is none.
    A reserve larger than the limit would be refused with SIGXFSZ."""
    if resource is not None:
        soft = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
        if soft != resource.RLIM_INFINITY:
            return int(soft)
    return 1 << 62
