"""Third-party programs the tests use (runuser, initdb/pg_ctl, chromium, mbpoll, apt-get), found where
Debian and other Unix systems put them, whatever PATH the suite was started with.

A shell started with ``env -i PATH=/usr/bin:/bin`` (or by cron, or a CI wrapper) has no sbin on PATH,
yet ``/usr/sbin/runuser`` is there; programs that are not meant to be run by hand live in libexec or
in a package's own directory (PostgreSQL's server programs in ``/usr/lib/postgresql/<major>/bin``).
:func:`find_program` looks on PATH first, then in those places. Standard library only: ``dev.py``
uses it before any environment exists.
"""

from __future__ import annotations

import glob
import os
import re
import shutil

SYSTEM_DIRS: tuple[str, ...] = ("/usr/local/sbin", "/usr/local/bin", "/usr/sbin", "/usr/bin", "/sbin", "/bin")
"""The standard program directories of the Filesystem Hierarchy Standard (FHS 3.0, sections 4.4 and 4.10):
root's PATH on Debian (``/etc/profile``, ``/etc/login.defs`` ENV_SUPATH) in that order."""

LIBEXEC_DIRS: tuple[str, ...] = ("/usr/local/libexec", "/usr/libexec", "/usr/lib/*", "/usr/lib/*/bin", "/usr/lib/*/*/bin")
"""Programs run by other programs rather than users (FHS 3.0 section 4.7: ``/usr/libexec``; Debian puts
them in ``/usr/lib/<package>``, e.g. ``/usr/lib/chromium/chromium``, ``/usr/lib/postgresql/15/bin/pg_ctl``).
Glob patterns; where several match, the highest version number wins."""


def _version_key(path: str) -> tuple:
    """Sort key: the numbers in ``path`` compared as numbers (``postgresql/9`` before ``postgresql/15``)."""
    return tuple(int(n) for n in re.findall(r"\d+", path)), path


def find_program(name: str) -> str | None:
    """Absolute path of the executable ``name``: on PATH, else in :data:`SYSTEM_DIRS`, else in
    :data:`LIBEXEC_DIRS` (the highest version where several match); None where it is not installed."""
    found = shutil.which(name) or shutil.which(name, path=os.pathsep.join(SYSTEM_DIRS))
    if found:
        return found
    for pattern in LIBEXEC_DIRS:
        matches = [p for p in glob.glob(os.path.join(pattern, name)) if os.path.isfile(p) and os.access(p, os.X_OK)]
        if matches:
            return max(matches, key=_version_key)
    return None


def with_system_dirs(path: str | None) -> str:
    """``path`` (a PATH value, possibly empty) followed by those :data:`SYSTEM_DIRS` it lacks: for child
    processes that find their own helpers on PATH (apt-get runs dpkg, which wants ``ldconfig`` and
    ``start-stop-daemon`` from ``/usr/sbin`` and ``/sbin``)."""
    parts = [p for p in (path or "").split(os.pathsep) if p]
    return os.pathsep.join(parts + [d for d in SYSTEM_DIRS if d not in parts])
