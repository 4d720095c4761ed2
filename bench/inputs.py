"""Reading input files safely: bounded in size, regular files only, confined to known trees.

Every YAML document (procedure, called sub-procedure, lab config, sensor model, calibration file,
vibration profile, answers file) and every measured-data CSV is read through
:func:`read_input_bytes`, which refuses in well under a second, with a located
:class:`~bench.errors.InputError` (exit code 2):

* anything that is not a regular file (``/dev/zero``, ``/dev/urandom``, a FIFO, a directory):
  checked with ``os.stat`` before opening, and the file is opened ``O_NONBLOCK`` so that a FIFO
  swapped in between never blocks;
* a file larger than its limit: :data:`YAML_LIMIT_BYTES` (1 MiB) for YAML documents,
  :data:`CSV_LIMIT_BYTES` (256 MiB) for CSV data. At most ``limit + 1`` bytes are ever read, so a
  file that grows while it is read is refused too.

Files named *inside* an input (``call: procedure``, ``vibrate: profile`` of a procedure;
``sensor_model:``, ``calibration:`` of a config) go through :func:`confined_path` first: the name
is taken relative to the naming file's directory and must resolve (symbolic links followed) inside
that directory's tree or one of the project's trees (``procedures/``, ``configs/`` next to the
``bench`` package). Absolute names and ``..`` that leave those trees are refused, so no message
ever quotes a line of a foreign file such as ``/etc/passwd``.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import Sequence

from bench.errors import InputError, Location

YAML_LIMIT_BYTES = 1 << 20
"""Largest procedure, config, sensor model, calibration file, vibration profile or answers file (1 MiB)."""
CSV_LIMIT_BYTES = 256 << 20
"""Largest measured-data CSV file (256 MiB)."""
NOT_REGULAR = "not a regular file (a directory, device or FIFO)"

PROJECT_ROOT = Path(__file__).resolve().parent.parent
"""The checkout holding the ``bench`` package and the shipped ``procedures/`` and ``configs/``."""
PROCEDURE_ROOTS = (PROJECT_ROOT / "procedures", PROJECT_ROOT / "configs")
"""Trees a procedure may name files in, besides its own directory's tree."""
CONFIG_ROOTS = (PROJECT_ROOT / "configs",)
"""Trees a config may name files in, besides its own directory's tree."""


def _size_text(n: int) -> str:
    return f"{n >> 20} MiB" if n >= 1 << 20 and n % (1 << 20) == 0 else f"{n} bytes"


def read_input_bytes(path: str | Path, *, limit_bytes: int, what: str,
                     location: Location | None = None, field: str | None = None) -> bytes:
    """The bytes of the regular file ``path`` (at most ``limit_bytes``); :class:`InputError`
    located at ``location`` (default: the file itself) for a missing, special or oversized file."""
    p = Path(path)
    loc = location if location is not None else Location(p)

    def refuse(problem: str) -> InputError:
        return InputError(f"cannot read {what}: {problem}", loc, field)

    fd = _open_regular(p, what, loc, field, limit_bytes)
    try:
        chunks: list[bytes] = []
        left = limit_bytes + 1
        while left > 0:
            chunk = os.read(fd, min(left, 1 << 20))
            if not chunk:
                break
            chunks.append(chunk)
            left -= len(chunk)
    except OSError as exc:
        raise refuse(exc.strerror or type(exc).__name__) from None
    finally:
        os.close(fd)
    data = b"".join(chunks)
    if len(data) > limit_bytes:  # grew while being read
        raise refuse(f"the file is larger than {_size_text(limit_bytes)}")
    return data


def _open_regular(p: Path, what: str, loc: Location, field: str | None, limit_bytes: int | None = None) -> int:
    """A read-only descriptor of the regular file ``p`` (at most ``limit_bytes`` long), opened so
    that a FIFO never blocks: ``os.stat`` first, then ``O_NONBLOCK`` and ``fstat`` (a FIFO or
    device swapped in meanwhile is refused too). :class:`InputError` otherwise."""

    def refuse(problem: str) -> InputError:
        return InputError(f"cannot read {what}: {problem}", loc, field)

    try:
        st = os.stat(p)
    except FileNotFoundError:
        raise InputError(f"{what} not found", loc, field) from None
    except ValueError:  # a NUL byte in the name
        raise refuse("expected a file name without NUL characters") from None
    except OSError as exc:
        raise refuse(exc.strerror or type(exc).__name__) from None
    if not stat.S_ISREG(st.st_mode):
        raise refuse(NOT_REGULAR)
    if limit_bytes is not None and st.st_size > limit_bytes:
        raise refuse(f"the file is larger than {_size_text(limit_bytes)}")
    try:
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise refuse(exc.strerror or type(exc).__name__) from None
    if not stat.S_ISREG(os.fstat(fd).st_mode):  # replaced by something else since the stat
        os.close(fd)
        raise refuse(NOT_REGULAR)
    return fd


def read_head(path: str | Path, n: int, *, what: str = "data file", location: Location | None = None,
              field: str | None = None) -> bytes:
    """The first ``n`` bytes of the regular file ``path`` (fewer if it is shorter), read without ever
    blocking: a FIFO, device or directory is :class:`InputError` (``cannot read data file: not a
    regular file ...``), as :func:`read_input_bytes` refuses them. For the format checks of data
    files (``bench diagnose``, ``calibrate``, ``import``: HDF5 signature, netCDF-3 magic)."""
    p = Path(path)
    fd = _open_regular(p, what, location if location is not None else Location(p), field)
    try:
        return os.read(fd, n)
    except OSError as exc:
        raise InputError(f"cannot read {what}: {exc.strerror or type(exc).__name__}", location or Location(p), field) from None
    finally:
        os.close(fd)


def confined_path(name: str, *, base: Path, roots: Sequence[Path], what: str, where: str,
                  location: Location | None, field: str | None) -> Path:
    """``name`` (written in a file in directory ``base``) as an absolute path inside ``base``'s
    tree or one of ``roots``; :class:`InputError` at ``location``/``field`` otherwise. ``where``
    describes the allowed trees in the message (e.g. "the procedure's directory, procedures/ or configs/")."""
    if "\0" in name:
        raise InputError(f"cannot read {what}: expected a file name without NUL characters", location, field)
    try:
        allowed = [Path(base).resolve(), *(Path(r).resolve() for r in roots)]
        target = (Path(base) / name).resolve()
    except (OSError, RuntimeError) as exc:  # RuntimeError: a symbolic link loop (older Pythons)
        raise InputError(f"cannot read {what}: {getattr(exc, 'strerror', None) or type(exc).__name__}", location, field) from None
    if not any(target == a or target.is_relative_to(a) for a in allowed):
        raise InputError(f"cannot read {what}: the file is outside {where} "
                         "(absolute names and '..' may not leave them)", location, field)
    return target
