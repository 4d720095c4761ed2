"""The private temporary directory a replay reads its procedure and config from.

A run file holds texts (the procedure, the sub-procedures and vibration profiles it read, the lab
config and the sensor models and calibration files it read) and the paths they had when they were
recorded. A replay treats both as data: the texts
are written as files into a fresh directory of its own (``bench-replay-*`` under the system's
temporary directory, mode 0700, removed afterwards), each at its recorded absolute path *mirrored
below* that directory, so that the procedure and config loaders, which resolve the names a file
gives relative to that file (and confine them to its directory tree, bench/inputs.py), find the
recorded texts and nothing else. Recorded paths are checked before anything is created: plain
components only (no NUL, no empty, ``.`` or ``..`` component, at most :data:`NAME_MAX_BYTES` bytes
each and :data:`PATH_MAX_BYTES` in all); files are created exclusively and never through a
symbolic link, and nothing is ever created outside the directory.

Messages of the loaders name the mirrored paths; :meth:`Workspace.relocate` turns them back into
the recorded paths, located in the run file.
"""

from __future__ import annotations

import os
import shutil
import stat
import tempfile
from pathlib import Path, PurePosixPath

from bench.errors import InputError, InputErrors, Location

NAME_MAX_BYTES = 255
"""Longest path component a recorded path may have (bytes of UTF-8; POSIX ``NAME_MAX``)."""
PATH_MAX_BYTES = 4096
"""Longest recorded path (bytes of UTF-8; Linux ``PATH_MAX``)."""
SHOWN_CHARS = 80
"""How much of a refused recorded path a message shows."""


def shown(text: object) -> str:
    """A text from a run file as a message shows it: ``repr`` (control characters escaped, so it
    cannot forge lines of the output), cut to :data:`SHOWN_CHARS` characters."""
    r = repr(text)
    return r if len(r) <= SHOWN_CHARS else r[:SHOWN_CHARS - 5] + "...'"


def checked_path(text: object, run_file: Path, what: str, *, absolute: bool) -> PurePosixPath:
    """``text`` (a path recorded in ``run_file``, described by ``what``) as a normalised POSIX path
    of plain components; :class:`InputError` naming the run file when it is not one. ``absolute``:
    it must be absolute and already normalised (paths bench records after resolving them); else a
    relative path is accepted and ``.``/``..`` are removed lexically (it only places a text)."""

    def refuse(problem: str) -> InputError:
        return InputError(f"{run_file}: {what} {shown(text)}: {problem}; the run file was not written by bench or was altered")

    if not isinstance(text, str) or not text:
        raise refuse("expected a non-empty file path")
    if "\0" in text:
        raise refuse("a path with a NUL character")
    raw = text.encode("utf-8", errors="surrogateescape")
    if len(raw) > PATH_MAX_BYTES:
        raise refuse(f"a path longer than {PATH_MAX_BYTES} bytes")
    p = PurePosixPath(text)
    if absolute:
        if not p.is_absolute() or os.path.normpath(text) != text or text.startswith("//"):
            raise refuse("expected an absolute path without '.' or '..' components")
    else:
        p = PurePosixPath(os.path.normpath(text).lstrip("/") or ".")
        p = PurePosixPath(*[c for c in p.parts if c != ".."]) if ".." in p.parts else p
    parts = [c for c in p.parts if c != "/"]
    if not parts or parts[-1] in (".", ".."):
        raise refuse("expected the path of a file")
    for c in parts:
        if len(c.encode("utf-8", errors="surrogateescape")) > NAME_MAX_BYTES:
            raise refuse(f"a path component longer than {NAME_MAX_BYTES} bytes")
    return PurePosixPath("/", *parts) if absolute else PurePosixPath(*parts)


class Workspace:
    """A fresh private directory holding run-file texts at their mirrored recorded paths."""

    def __init__(self, run_file: Path):
        self.run_file = Path(run_file)
        self.root = Path(tempfile.mkdtemp(prefix="bench-replay-"))  # mode 0700, a new name
        self.tree = self.root / "tree"
        os.mkdir(self.tree, 0o700)
        self._where: dict[str, str] = {}
        """mirrored path -> where its text comes from (for messages)."""

    def __enter__(self) -> Workspace:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        shutil.rmtree(self.root, ignore_errors=True)

    def mirrored(self, recorded: PurePosixPath) -> Path:
        """Where the text recorded at ``recorded`` (absolute, from :func:`checked_path`) goes."""
        return self.tree.joinpath(*recorded.parts[1:])

    def write(self, recorded: PurePosixPath, text: str, where: str) -> Path:
        """Write ``text`` at the mirror of ``recorded`` (absolute, checked); ``where`` says where the
        text comes from, as messages locate it (``RUN.h5:/procedure/text``, a project file).
        Directories are created as needed, never through a symbolic link; the same text written
        twice at one place is fine, another text there is refused."""
        target = self.mirrored(recorded)
        d = self.tree
        for part in recorded.parts[1:-1]:
            d = d / part
            try:
                os.mkdir(d, 0o700)
            except FileExistsError:
                pass
            except OSError as exc:
                raise InputError(f"{where}: recorded path {shown(str(recorded))} cannot be placed: "
                                 f"{exc.strerror or type(exc).__name__}") from None
            if not stat.S_ISDIR(os.lstat(d).st_mode):  # a file of another recorded path, or a link
                raise InputError(f"{where}: recorded path {shown(str(recorded))} runs through another recorded file")
        data = text.encode("utf-8", errors="surrogateescape")
        flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
        try:
            fd = os.open(target, flags, 0o600)
        except FileExistsError:
            if stat.S_ISREG(os.lstat(target).st_mode) and target.read_bytes() == data:
                return target
            raise InputError(f"{where}: recorded path {shown(str(recorded))} holds two different texts") from None
        except OSError as exc:  # too long once below the private directory, ...
            raise InputError(f"{where}: recorded path {shown(str(recorded))} cannot be placed: "
                             f"{exc.strerror or type(exc).__name__}") from None
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        self._where[str(target)] = where
        return target

    def relocate(self, exc: InputError) -> InputError:
        """``exc`` (from a loader reading the mirrored texts) located in the run file: a location in
        a mirrored file becomes ``RUN.h5:<where the text is>:line:column``; mirrored paths in the
        message become the recorded paths."""
        errors = exc.errors if isinstance(exc, InputErrors) else [exc]
        out = []
        for e in errors:
            loc = e.location
            if loc is not None and str(loc.file) in self._where:
                loc = Location(self._where[str(loc.file)], loc.line, loc.column)
            elif loc is not None and str(loc.file).startswith(str(self.tree) + os.sep):
                loc = Location(f"{self.run_file}: {self._unmirror(str(loc.file))}", loc.line, loc.column)
            out.append(InputError(self._unmirror(e.message), loc, e.field))
        return InputErrors(out) if isinstance(exc, InputErrors) else out[0]

    def recorded(self, path: str | Path) -> str:
        """The recorded path a mirrored ``path`` stands for (any other path unchanged)."""
        return self._unmirror(str(path))

    def _unmirror(self, text: str) -> str:
        return text.replace(str(self.tree) + os.sep, "/")
