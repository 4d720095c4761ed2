"""The entry points of one group as :mod:`importlib.metadata` finds them, kept on disk between runs.

``importlib.metadata.entry_points(group=...)`` opens the metadata of every installed distribution:
about 4 ms of every command that reads a kind with the ~100 distributions of bench's test set-up,
more in a big environment. What it found is written to
``$XDG_CACHE_HOME/bench/kinds/<hash of sys.path>.txt`` (:func:`bench.user_cache.user_cache_dir`)
with a fingerprint of where it looked: the modification time of every ``sys.path`` entry and of each
declaring distribution's ``entry_points.txt``. Installing, upgrading or removing a distribution
(pip, editable installs included) adds or removes a directory in a ``sys.path`` entry, so the next
command reads the metadata again; so does editing a declaring distribution's entry points.

Not seen: an ``entry_points.txt`` edited in place (not by pip) in a distribution that did not
declare the group before. ``bench instruments kinds`` always reads the metadata afresh and rewrites
the cache; deleting the directory is always safe. A cache that cannot be read or written is
ignored; at most :data:`KEEP` files are kept.
"""

from __future__ import annotations

import os
import sys
import zlib

from bench.user_cache import user_cache_dir

Entry = tuple[str, str, str]
"""One entry point: (distribution name, entry point name, value ``"module:attr"``)."""

_MAGIC = "bench entry points v1"
KEEP = 16
"""Cache files kept (one per ``sys.path``: ``python -m bench`` puts the working directory first);
the oldest beyond these are removed when one is written."""


def scan(group: str) -> tuple[list[Entry], list[str] | None]:
    """The group's entry points read from the installed distributions' metadata, in
    :mod:`importlib.metadata`'s order, and the ``entry_points.txt`` files they come from (None
    when a distribution has no such file: nothing can then be cached)."""
    from importlib.metadata import entry_points

    found: list[Entry] = []
    files: list[str] | None = []
    names: dict[int, str] = {}  # a distribution's name parses its METADATA: once per distribution
    for ep in entry_points(group=group):
        dist = getattr(ep, "dist", None)
        if id(dist) not in names:
            names[id(dist)] = getattr(dist, "name", "") or "?"
            where = getattr(dist, "_path", None)  # a PathDistribution's .dist-info/.egg-info directory
            if where is None or files is None:
                files = None
            else:
                files.append(os.path.join(str(where), "entry_points.txt"))
        found.append((names[id(dist)], ep.name, ep.value))
    return found, files


def entries(group: str, *, fresh: bool = False) -> list[Entry]:
    """The group's entry points (see the module docstring): from the cache when nothing it was
    made from has changed, unless ``fresh``; else read (and cached)."""
    path = user_cache_dir("kinds") / f"{zlib.crc32(repr(sys.path).encode()):08x}.txt"
    head = _head(group)
    if head is not None and not fresh:
        hit = _read(path, head)
        if hit is not None:
            return hit
    found, files = scan(group)
    if head is not None and files is not None:
        _write(path, head, files, found)
    return found


def _mtime(path: str) -> str:
    try:
        return str(os.stat(path).st_mtime_ns)
    except OSError:
        return "-"


def _head(group: str) -> list[str] | None:
    """The fingerprint's first lines: interpreter, group, each ``sys.path`` entry's time (None:
    a path that cannot be written on one line)."""
    lines = [_MAGIC, f"python\t{sys.version}\t{sys.executable}", f"group\t{group}"]
    for entry in sys.path:
        if "\n" in entry or "\t" in entry:
            return None
        lines.append(f"path\t{entry}\t{_mtime(entry or '.')}")
    return lines


def _read(path: os.PathLike[str], head: list[str]) -> list[Entry] | None:
    try:
        with open(path, encoding="utf-8") as f:
            lines = f.read().split("\n")
    except (OSError, UnicodeError):
        return None
    if lines[:len(head)] != head:
        return None
    found: list[Entry] = []
    for line in lines[len(head):]:
        tag, _, rest = line.partition("\t")
        if tag == "file":
            name, _, when = rest.rpartition("\t")
            if _mtime(name) != when:
                return None
        elif tag == "ep":
            parts = rest.split("\t")
            if len(parts) != 3:
                return None
            found.append((parts[0], parts[1], parts[2]))
        elif tag == "end":
            return found
        else:
            return None
    return None  # no end line: a file cut short


def _write(path: os.PathLike[str], head: list[str], files: list[str], found: list[Entry]) -> None:
    if any("\n" in x or "\t" in x for e in found for x in e) or any("\n" in f or "\t" in f for f in files):
        return
    lines = [*head, *(f"file\t{f}\t{_mtime(f)}" for f in files), *(f"ep\t{d}\t{n}\t{v}" for d, n, v in found), "end", ""]
    tmp = f"{os.fspath(path)}.{os.getpid()}.tmp"
    try:
        os.makedirs(os.path.dirname(tmp), exist_ok=True)
        with open(tmp, "w", encoding="utf-8") as f:
            f.write("\n".join(lines))
        os.replace(tmp, path)
    except OSError:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        return
    _prune(os.path.dirname(tmp))


def _prune(directory: str) -> None:
    """Remove all but the :data:`KEEP` newest cache files of ``directory``."""
    try:
        with os.scandir(directory) as it:
            files = sorted(((e.stat().st_mtime_ns, e.path) for e in it if e.name.endswith(".txt")), reverse=True)
        for _, old in files[KEEP:]:
            os.unlink(old)
    except OSError:
        pass
