"""Which run files a fleet works on, the name each is known by, and where its output goes.

A fleet's files are the ``*.h5`` files of a directory and its subdirectories
(:func:`files_in`, sorted by path, the same files ``bench catalog rebuild --recursive`` catalogues:
a link that leads out of the directory is skipped with a warning),
or the files of catalogue rows (:func:`files_of_rows`). Each file is known by its path relative to
a root (the directory, or the deepest directory common to the catalogue's files): ``sub/a.h5``.
Its output is named after it inside the output directory (:func:`destination`):
``OUT/sub/a.html`` for a report, ``OUT/sub/a.noise.json`` for a calibration, ``OUT/sub/`` for the
replay's own run file. A relative name never climbs out (no ``..``, never absolute), so no output
lands outside the output directory.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any, Callable, Iterable, Sequence

from bench.errors import InputError
from bench.outputs import output_file

COMMANDS = ("replay", "calibrate", "diagnose", "report")
"""What a fleet can do with each file: the serial command of the same name."""


@dataclass(frozen=True)
class RunFileRef:
    """One file of a fleet: its ``path`` (as given or found) and its relative name ``rel`` (POSIX
    separators) under the fleet's root."""

    path: Path
    rel: str


def files_in(directory: Path, *, exclude: Path | None = None, warn: Callable[[str], None] | None = None) -> list[RunFileRef]:
    """The ``*.h5`` files of ``directory`` and its subdirectories, sorted by path, except those under
    ``exclude`` (the output directory, when it lies inside) and links that lead out of ``directory``
    (not its runs, as ``bench catalog rebuild`` skips them: each reason passed to ``warn``).
    :class:`InputError` on ``DIR`` when ``directory`` is not a directory or holds no run file."""
    from bench.catalog.rebuild import outside, run_files

    directory = Path(directory)
    if not directory.is_dir():
        raise InputError(f"{directory}: {'not a directory' if directory.exists() else 'no such directory'}", None, "DIR")
    skip = Path(exclude).resolve() if exclude is not None else None
    refs = []
    for path in run_files(directory, recursive=True):
        if skip is not None and (path.resolve() == skip or skip in path.resolve().parents):
            continue
        link_out = outside(path, directory)
        if link_out:
            if warn is not None:
                warn(link_out)
            continue
        refs.append(RunFileRef(path, path.relative_to(directory).as_posix()))
    if not refs:
        raise InputError(f"{directory}: no *.h5 run file in it or below", None, "DIR")
    return refs


def files_of_rows(rows: Iterable[dict[str, Any]]) -> list[RunFileRef]:
    """The files of catalogue rows (their absolute ``path``), named relative to the deepest directory
    they have in common. :class:`InputError` on ``--query`` when no row matched."""
    paths = [Path(r["path"]) for r in rows]
    if not paths:
        raise InputError("no catalogued run matches the filters", None, "--query")
    root = Path(os.path.commonpath([p.parent for p in paths]))
    return [RunFileRef(p, p.relative_to(root).as_posix()) for p in paths]


def _safe_rel(rel: str) -> PurePosixPath:
    """``rel`` as a relative path that stays where it is put: ``ValueError`` for an absolute name or
    one with ``..`` (never made by this module; refused in case a caller does)."""
    p = PurePosixPath(rel)
    if p.is_absolute() or ".." in p.parts or not p.parts:
        raise ValueError(f"not a relative run-file name: {rel!r}")
    return p


def output_suffix(command: str, method: str | None = None) -> str:
    """What a command's output adds to the run file's stem: ``.html`` (report),
    ``.diagnose.json``, ``.METHOD.json`` (calibrate); ``""`` for replay (its output is a directory)."""
    return {"report": ".html", "diagnose": ".diagnose.json", "calibrate": f".{method}.json", "replay": ""}[command]


def destination(out_dir: Path, rel: str, command: str, method: str | None = None) -> Path:
    """Where the output of the file named ``rel`` goes: a file named after it (report, diagnose,
    calibrate), or for replay the directory its replay's run file is recorded in; inside
    ``out_dir`` in every case."""
    r = _safe_rel(rel)
    parent = Path(out_dir).joinpath(*r.parent.parts)
    if command == "replay":
        return parent
    return parent / (r.stem + output_suffix(command, method))


def existing_outputs(out_dir: Path, refs: Sequence[RunFileRef], command: str, method: str | None = None) -> list[Path]:
    """The output files of ``refs`` that exist already (none for replay, whose run files are new)."""
    if command == "replay":
        return []
    return [d for d in (destination(out_dir, r.rel, command, method) for r in refs) if os.path.lexists(d)]


def write_new(path: Path, write: Callable[[Path], None], *, force: bool) -> None:
    """Have ``write`` write a hidden sibling of ``path``, then move it to ``path`` (:func:`bench.outputs.output_file`):
    a reader never sees a half-written output; an existing ``path`` is replaced only with ``force``.
    Parent directories are made."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with output_file(path, "--out", force=force) as tmp:
        write(tmp)
