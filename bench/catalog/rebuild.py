"""Rebuilding the catalogue from the run files: the files are the truth, the catalogue an index.

:func:`rebuild` reads every ``*.h5`` file of a directory (with ``recursive``, of its
subdirectories too) and upserts its row keyed by the file's absolute path, so running it again
changes nothing but what the files changed. A file that is not a readable run file is reported and
skipped; the others are catalogued. Rows are written in batches (one short transaction per
:data:`BATCH_FILES` files or :data:`BATCH_WALL_S` of reading), so a live run can update its own row
meanwhile.

A file is catalogued only when it is in the directory: a symbolic link that leads out of it (a
file or a directory elsewhere) is skipped and listed, so the runs of a directory are never another
directory's files. A file whose name is not UTF-8 cannot be a catalogue key (SQLite and PostgreSQL
store text) and is listed as unreadable with the advice to rename it; the others are catalogued.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from bench.catalog.row import run_row
from bench.catalog.store import Catalog
from bench.errors import InputError
from bench.record.reader import STALE_AFTER_S
from bench.terminal_text import printable

RUN_FILE_GLOB = "*.h5"
BATCH_FILES = 200
"""Rows upserted per transaction at most."""
BATCH_WALL_S = 2.0
"""Longest reading time (s of wall time) before the rows read so far are written."""


@dataclass
class RebuildReport:
    """What a rebuild did: files seen, rows written, unreadable files with the reason, files skipped
    (links out of the directory) with the reason, wall time (s)."""

    files: int = 0
    catalogued: int = 0
    unreadable: list[tuple[Path, str]] = field(default_factory=list)
    wall_s: float = 0.0
    skipped: list[tuple[Path, str]] = field(default_factory=list)

    @property
    def files_per_s(self) -> float:
        """Files read (catalogued or not) per second of wall time."""
        return self.files / self.wall_s if self.wall_s > 0 else 0.0


def run_files(directory: Path, recursive: bool = False) -> list[Path]:
    """The ``*.h5`` files of ``directory`` (and below with ``recursive``), sorted by path (links
    included: :func:`outside` tells which lead out of the directory)."""
    pattern = f"**/{RUN_FILE_GLOB}" if recursive else RUN_FILE_GLOB
    return sorted(p for p in Path(directory).glob(pattern) if p.is_file())


def outside(path: Path, directory: Path) -> str:
    """Why the run file ``path`` found in ``directory`` is not catalogued as one of its runs: a
    symbolic link (of the file or a directory above it) that resolves outside ``directory``;
    ``""`` when it is inside."""
    try:
        target = Path(path).resolve()
        base = Path(directory).resolve()
    except (OSError, RuntimeError) as exc:
        return f"{printable(path)}: cannot be resolved ({getattr(exc, 'strerror', None) or exc})"
    if target == base or base in target.parents:
        return ""
    return f"{printable(path)}: a link to {printable(target)}, outside {printable(directory)}: not one of its runs, skipped"


def unnameable(path: Path) -> str:
    """Why ``path`` cannot be a catalogue key (a name that is not UTF-8), or ``""``."""
    try:
        str(Path(path).resolve()).encode("utf-8")
    except UnicodeEncodeError:
        return (f"{printable(path)}: the file name is not UTF-8, so the catalogue cannot hold it (SQLite and PostgreSQL "
                "store text): rename it, then rebuild")
    return ""


def rebuild(cat: Catalog, directory: Path, *, recursive: bool = False,
            on_file: Callable[[int, int, Path], None] | None = None,
            stale_after_s: float = STALE_AFTER_S, now_unix: float | None = None) -> RebuildReport:
    """Upsert the row of every run file of ``directory`` into ``cat``; ``on_file(done, total,
    path)`` after each file. ``stale_after_s``/``now_unix`` (s) decide ``crashed`` as the reader does.
    Raises :class:`InputError` when ``directory`` is not a directory."""
    directory = Path(directory)
    if not directory.is_dir():
        raise InputError(f"{directory}: not a directory" if directory.exists() else f"{directory}: no such directory", None, "DIR")
    t0 = time.perf_counter()
    files = run_files(directory, recursive)
    report = RebuildReport(files=len(files))
    batch: list[dict[str, Any]] = []
    t_batch = time.perf_counter()
    for i, path in enumerate(files, 1):
        link_out = outside(path, directory)
        bad_name = "" if link_out else unnameable(path)
        if link_out:
            report.skipped.append((path, link_out))
        elif bad_name:
            report.unreadable.append((path, bad_name))
        else:
            _read_row(path, batch, report, stale_after_s, now_unix)
        if len(batch) >= BATCH_FILES or (batch and time.perf_counter() - t_batch >= BATCH_WALL_S):
            report.catalogued += cat.upsert(batch)
            batch, t_batch = [], time.perf_counter()
        if on_file is not None:
            on_file(i, len(files), path)
    report.catalogued += cat.upsert(batch)
    report.wall_s = time.perf_counter() - t0
    return report


def _read_row(path: Path, batch: list[dict[str, Any]], report: RebuildReport, stale_after_s: float, now_unix: float | None) -> None:
    """The row of ``path`` into ``batch``, or the reason it cannot be read into ``report``."""
    try:
        batch.append(run_row(path, stale_after_s=stale_after_s, now_unix=now_unix))
    except InputError as exc:
        report.unreadable.append((path, exc.message))
    except OSError as exc:  # the file vanished or cannot be read while hashing
        report.unreadable.append((path, f"{printable(path)}: {exc.strerror or exc}"))
