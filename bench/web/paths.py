"""Run ids and procedure names from requests, mapped to files inside their directory only.

A run id is the run file's path relative to the runs directory, in POSIX form
(``20261123T101500Z_startup_profile.h5``, ``soak/…h5``). Anything else is refused: an absolute
path, ``..``, a backslash or NUL, a name that does not end in ``.h5``, and any path (a symlink
included) that resolves outside the directory. Nothing from a request is ever used as a path
without going through here.
"""

from __future__ import annotations

from pathlib import Path, PurePosixPath

from bench.errors import InputError

RUN_SUFFIX = ".h5"
PROCEDURE_SUFFIXES = (".yaml", ".yml")


def _inside(root: Path, rel: str, suffixes: tuple[str, ...], what: str) -> Path:
    """``root/rel`` after checking ``rel`` is a relative POSIX path without ``..`` that resolves
    inside ``root`` and names a file with one of ``suffixes``; else :class:`InputError`."""
    if not rel or "\\" in rel or "\x00" in rel or len(rel) > 1024:
        raise InputError(f"bad {what} {rel!r}")
    p = PurePosixPath(rel)
    if p.is_absolute() or any(part in ("..", "") for part in p.parts) or p.suffix.lower() not in suffixes:
        raise InputError(f"bad {what} {rel!r}: expected a {'/'.join(suffixes)} file inside the directory")
    base = root.resolve()
    target = (base / Path(*p.parts)).resolve()
    if base != target and base not in target.parents:
        raise InputError(f"bad {what} {rel!r}: outside the directory")
    if not target.is_file():
        raise InputError(f"no {what} {rel!r}")
    return target


def run_path(runs_dir: Path, run_id: str) -> Path:
    """The run file of ``run_id`` inside ``runs_dir`` (:class:`InputError` if refused or absent)."""
    return _inside(runs_dir, run_id, (RUN_SUFFIX,), "run id")


def run_id(runs_dir: Path, path: Path) -> str | None:
    """The run id of ``path`` (None when it is not inside ``runs_dir``)."""
    try:
        return Path(path).resolve().relative_to(Path(runs_dir).resolve()).as_posix()
    except ValueError:
        return None


def procedure_path(library: Path, name: str) -> Path:
    """The procedure file ``name`` of the library directory (:class:`InputError` if refused or absent)."""
    return _inside(library, name, PROCEDURE_SUFFIXES, "procedure")
