"""A SHA-256 over a run file's attributes and texts, so that ``bench inspect --verify`` sees a
changed status, procedure name or start time.

HDF5 checksums the chunks of the streams and the event log (Fletcher-32, :mod:`bench.record.chunks`)
but not attributes or contiguous datasets: a bit flipped in the ``status`` attribute (``completed`` →
``compmeted``), the procedure name or the start time read back without any error. The recorder
therefore stores :data:`~bench.record.layout.ATTR_DIGEST`, the SHA-256 of every link of the file (its
structure: an object added, removed or linked elsewhere changes it), every attribute of every object
(the root, instruments, streams and their columns, the texts; names sorted, values with their type)
and the procedure and config texts, twice: when the file is switched to SWMR mode
(attributes cannot change after that until the file is finalised, so a crashed file keeps a valid one)
and again when the final status is written. Not covered: the heartbeat (it changes during the run) and
the stream and event data (their chunks have their own checksums).
"""

from __future__ import annotations

import hashlib
from typing import Any

import h5py
import numpy as np

from bench.record import layout

DIGEST_ALGORITHM = "sha256"


def _canonical(value: Any) -> bytes:
    """An attribute value as bytes that differ whenever the value or its type does."""
    if isinstance(value, str):
        return b"s" + value.encode("utf-8", errors="surrogateescape")
    if isinstance(value, bytes):
        return b"b" + value
    a = np.asarray(value)
    if a.dtype.kind == "O":
        return b"o" + repr(a.tolist()).encode("utf-8", errors="backslashreplace")
    return b"n" + a.dtype.str.encode() + repr(a.shape).encode() + np.ascontiguousarray(a).tobytes()


def attributes_digest(f: h5py.File) -> str:
    """The hex SHA-256 of the attributes of every object of ``f`` (except the digest itself) and of
    the text datasets (:data:`layout.PROCEDURE_TEXT`, :data:`layout.CONFIG_TEXT`). h5py and HDF5
    errors (a damaged file) propagate."""
    objects: list[Any] = [f]
    f.visititems(lambda _name, obj: objects.append(obj))
    h = hashlib.sha256()
    links: list[str] = []  # the structure: every link, hard or not (a link added to nothing is a change too)
    f.visititems_links(lambda name, link: links.append(f"{name}\0{type(link).__name__}\0{getattr(link, 'path', '')}"))
    for text in sorted(links):
        part = text.encode("utf-8", errors="surrogateescape")
        h.update(len(part).to_bytes(8, "little"))
        h.update(part)
    for obj in sorted(objects, key=lambda o: o.name):
        for key in sorted(obj.attrs.keys()):
            if obj.name == "/" and key == layout.ATTR_DIGEST:
                continue
            for part in (obj.name.encode(), key.encode("utf-8", errors="surrogateescape"), _canonical(obj.attrs[key])):
                h.update(len(part).to_bytes(8, "little"))
                h.update(part)
    for name in (layout.PROCEDURE_TEXT, layout.CONFIG_TEXT):
        if name in f:
            raw = np.asarray(f[name][()]).tobytes()
            h.update(name.encode() + len(raw).to_bytes(8, "little"))
            h.update(raw)
    return h.hexdigest()


def write_digest(f: h5py.File) -> None:
    """Store :func:`attributes_digest` of ``f`` (open for writing, not in SWMR mode) as
    :data:`layout.ATTR_DIGEST` (``sha256:<hex>``)."""
    f.attrs[layout.ATTR_DIGEST] = f"{DIGEST_ALGORITHM}:{attributes_digest(f)}"


def check_digest(f: h5py.File) -> str:
    """``verified`` (the stored digest matches), ``changed`` (it does not: an attribute or a text
    was altered since it was written), ``absent`` (a file written before digests, or by another
    program)."""
    if layout.ATTR_DIGEST not in f.attrs:
        return "absent"
    stored = f.attrs[layout.ATTR_DIGEST]
    stored = stored.decode("utf-8", errors="replace") if isinstance(stored, bytes) else str(stored)
    return "verified" if stored == f"{DIGEST_ALGORITHM}:{attributes_digest(f)}" else "changed"
