"""Rebuilding the catalogue from the run files: the files are the truth, the catalogue an index.

:func:`rebuild` reads every ``*.h5`` file of a directory (with ``recursive``, of its
subdirectories too) and upserts its row keyed by the file's absolute path, so running it again
changes nothing but what the files changed. A file that is not a readable run file is reported and
skipped; the others are catalogued. Rows are written in batches (one short transaction per
:data:`BATCH_FILES` files or :data:`BATCH_WALL_S` of reading), so a live run can update its own row
meanwhile.
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

RUN_FILE_GLOB = "*.h5"
BATCH_FILES = 200
"""Rows upserted per transaction at most."""
BATCH_WALL_S = 2.0
"""Longest reading time (s of wall time) before the rows read so far are written."""


@dataclass
class RebuildReport:
    """What a rebuild did: files seen, rows written, unreadable files with the reason, wall time (s)."""

    files: int = 0
    catalogued: int = 0
    unreadable: list[tuple[Path, str]] = field(default_factory=list)
    wall_s: float = 0.0

    @property
    def files_per_s(self) -> float:
        """Files read (catalogued or not) per second of wall time."""
        return self.files / self.wall_s if self.wall_s > 0 else 0.0


def run_files(directory: Path, recursive: bool = False) -> list[Path]:
    """The ``*.h5`` files of ``directory`` (and below with ``recursive``), sorted by path."""
    pattern = f"**/{RUN_FILE_GLOB}" if recursive else RUN_FILE_GLOB
    return sorted(p for p in Path(directory).glob(pattern) if p.is_file())


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
        try:
            batch.append(run_row(path, stale_after_s=stale_after_s, now_unix=now_unix))
        except InputError as exc:
            report.unreadable.append((path, exc.message))
        except OSError as exc:  # the file vanished or cannot be read while hashing
            report.unreadable.append((path, f"{path}: {exc.strerror or exc}"))
        if len(batch) >= BATCH_FILES or (batch and time.perf_counter() - t_batch >= BATCH_WALL_S):
            report.catalogued += cat.upsert(batch)
            batch, t_batch = [], time.perf_counter()
        if on_file is not None:
            on_file(i, len(files), path)
    report.catalogued += cat.upsert(batch)
    report.wall_s = time.perf_counter() - t0
    return report
