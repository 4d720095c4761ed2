"""Where a run file goes: refusing a runs directory that cannot take the run, the file name of a
run, and creating the file under a name that does not exist yet (never overwriting). A run's name
only ever holds a complete, readable file: files are written under hidden names first
(:func:`create_hidden`, :func:`create_partial`) and linked or moved to it.

Sizes in bytes; start times in UTC.
"""

from __future__ import annotations

import errno
import os
import re
import secrets
import shutil
import tempfile
from datetime import datetime
from pathlib import Path

import h5py

from bench.errors import DestinationError, RecorderError
from bench.record.layout import as_utc
from bench.record.reasons import mb, os_reason
from bench.record.streams import MAX_CHUNK_BYTES

SPACE_MARGIN_BYTES = 50 * 1024 * 1024
"""Free space (bytes) required on top of the estimated run-file size."""

SUFFIX = ".h5"
MAX_NAME_CHARS = 80
"""Longest procedure-name part of a run-file name (characters)."""
MAX_COLLISIONS = 10_000
"""Names ``_1`` … tried before giving up when the plain name exists."""

_NAME_BAD = re.compile(r"[^A-Za-z0-9._-]+")


def check_destination(runs_dir: Path, estimated_bytes: int) -> None:
    """Refuse a run before it starts if ``runs_dir`` cannot take its file.

    Creates ``runs_dir`` if needed, proves it writable by creating and deleting a temporary file,
    and requires ``estimated_bytes`` + 50 MB of free space (bytes, from ``shutil.disk_usage``).
    Raises :class:`DestinationError` naming the problem and the directory.
    """
    runs_dir = Path(runs_dir)
    make_runs_dir(runs_dir)
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
        raise DestinationError(f"runs directory {runs_dir} is not writable: {os_reason(exc)}") from None
    try:
        free = shutil.disk_usage(runs_dir).free
    except OSError as exc:
        raise DestinationError(f"free space of runs directory {runs_dir} cannot be determined: {os_reason(exc)}") from None
    need = max(int(estimated_bytes), 0) + SPACE_MARGIN_BYTES
    if free < need:
        raise DestinationError(
            f"not enough free space in runs directory {runs_dir}: {mb(free)} free, the run needs "
            f"{mb(need)} (estimated run file {mb(max(int(estimated_bytes), 0))} + {mb(SPACE_MARGIN_BYTES)} margin)"
        )


def make_runs_dir(runs_dir: Path) -> None:
    """Create ``runs_dir`` (and its parents) if needed; :class:`DestinationError` if that fails."""
    try:
        runs_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DestinationError(f"runs directory {runs_dir} cannot be created: {os_reason(exc)}") from None


def run_file_name(started_utc: datetime, procedure_name: str) -> str:
    """File name of a run: ``<YYYYMMDDTHHMMSSZ>_<procedure>.h5`` with the start time in UTC.

    The procedure name is reduced to ``[A-Za-z0-9._-]`` (other runs of characters become ``_``,
    at most 80 characters, ``run`` if nothing is left). A naive datetime is taken as UTC.
    """
    stamp = as_utc(started_utc).strftime("%Y%m%dT%H%M%SZ")
    name = _NAME_BAD.sub("_", procedure_name).strip("._-")[:MAX_NAME_CHARS].rstrip("._-") or "run"
    return f"{stamp}_{name}{SUFFIX}"


def create_hidden(runs_dir: Path, label: str) -> tuple[h5py.File, Path]:
    """A new HDF5 file (latest format, as SWMR needs) under a hidden name of ``runs_dir`` no other
    process uses (``.<label>.<pid>-<random>.new``), and its path. The run's placeholder is written
    there and then linked to the run's name (:func:`link_new_name`), so that name never holds a
    file being written. Raises :class:`DestinationError` if the directory cannot take the file,
    :class:`RecorderError` if HDF5 fails to create it."""
    runs_dir = Path(runs_dir)
    make_runs_dir(runs_dir)
    path = runs_dir / f".{label}.{os.getpid()}-{secrets.token_hex(4)}{NEW_SUFFIX}"
    try:
        # chunk cache of each dataset: one largest chunk (h5py's default, 8 MiB a dataset, filled as a run
        # grows and made the peak memory grow with run length, docs/benchmarks.md)
        return h5py.File(path, "x", libver="latest", rdcc_nbytes=MAX_CHUNK_BYTES), path
    except PermissionError as exc:
        raise DestinationError(f"run file {path} cannot be created: {os_reason(exc)}") from None
    except Exception as exc:  # noqa: BLE001 - h5py raises several types; report them all the same way
        _remove_new(path)
        raise RecorderError(f"writing {path} failed: {os_reason(exc)}") from None
    except BaseException:  # interrupted (KeyboardInterrupt) while HDF5 made the file: it holds nothing
        _remove_new(path)
        raise


def link_new_name(runs_dir: Path, started_utc: datetime, procedure_name: str, src: Path) -> Path:
    """Give the complete file ``src`` the run's name ``runs_dir/<run_file_name>`` (``_1``, ``_2`` …
    appended while the name exists) with a hard link, which fails rather than replace a file: an
    existing file is never touched. Returns the name. A file system without hard links gets a
    rename after an existence check instead. :class:`DestinationError` when no name is free."""
    base = run_file_name(started_utc, procedure_name)[: -len(SUFFIX)]
    for n in range(MAX_COLLISIONS):
        path = Path(runs_dir) / (f"{base}{SUFFIX}" if n == 0 else f"{base}_{n}{SUFFIX}")
        try:
            os.link(src, path)
            return path
        except FileExistsError:
            continue
        except OSError as exc:
            if exc.errno not in (errno.EPERM, errno.EOPNOTSUPP, errno.EXDEV):
                raise DestinationError(f"run file {path} cannot be created: {os_reason(exc)}") from None
            if os.path.lexists(path):
                continue
            os.rename(src, path)
            return path
    raise DestinationError(f"no free run-file name for {base} in {runs_dir}")


NEW_SUFFIX = ".new"


PARTIAL_SUFFIX = ".partial"


def partial_path(path: Path) -> Path:
    """Where the run file ``path`` is set up before it can be read: ``.<name>.partial`` beside it."""
    return path.with_name(f".{path.name}{PARTIAL_SUFFIX}")


def create_partial(path: Path) -> h5py.File:
    """Create the file that becomes the run file ``path`` once it can be read (:func:`partial_path`),
    replacing one a killed writer left there (``path`` was just created exclusively by this writer, so
    nobody else is setting that run up). :class:`RecorderError` if HDF5 fails."""
    partial = partial_path(path)
    try:
        os.unlink(partial)
    except OSError:
        pass
    try:
        return h5py.File(partial, "x", libver="latest", rdcc_nbytes=MAX_CHUNK_BYTES)
    except BaseException as exc:
        _remove_new(partial)
        if not isinstance(exc, Exception):
            raise
        raise RecorderError(f"writing {partial} failed: {os_reason(exc)}") from None


def _remove_new(path: Path) -> None:
    """Delete the file :func:`create_new_file` was making at ``path`` (the name did not exist just
    before, and HDF5's exclusive mode refuses an existing one), if it got as far as the disk."""
    try:
        os.unlink(path)
    except OSError:
        pass
