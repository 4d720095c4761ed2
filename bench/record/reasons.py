"""Short, one-line texts for what went wrong while writing a run file: the reason of an OS or HDF5
error, and sizes in MB. Used by every part of the writer so that its messages read alike."""

from __future__ import annotations

import re

_HDF5_REASON = re.compile(r"error message = '([^']*)'")
_ERRNO = re.compile(r"errno = (\d+)")


def os_reason(exc: BaseException) -> str:
    """Short reason of an OS/HDF5 error: the errno text when HDF5 reports one, else the message."""
    text = " ".join(str(exc).split())
    m = _HDF5_REASON.search(text)
    if m:
        errno_m = _ERRNO.search(text)
        what = text.split(" (", 1)[0]
        return f"{m.group(1)}" + (f" [errno {errno_m.group(1)}]" if errno_m else "") + f" ({what})"
    if isinstance(exc, OSError) and exc.strerror and exc.filename:
        return f"{exc.strerror}: {exc.filename}"
    return text or type(exc).__name__


def mb(n: int) -> str:
    """``n`` bytes as ``12.3 MB`` (10⁶ bytes)."""
    return f"{n / 1e6:.1f} MB"
