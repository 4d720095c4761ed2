"""The runs table of the web station, read without ever writing the catalogue on a request.

Before, every ``GET /api/runs`` added the run files the catalogue did not list yet, writing the
catalogue inside the request: with the catalogue write-locked by another process, 45 such
requests held every worker thread for their 10 s lock waits, and a ``POST /api/stop`` waited 30 s
behind them. Now a request only reads:

* the catalogue's rows for the filter (opened without writing: no WAL switch, no migration);
* the rows of the run files of the runs directory that the catalogue does not list, or lists as
  ``running`` (their writer may have died): read from the files themselves with the code of
  ``bench catalog rebuild`` (:func:`bench.catalog.row.run_row`), kept in memory while the file's
  size and time do not change, and filtered with the same SQL (an in-memory SQLite table);

and :class:`RunsIndex` hands those rows to one background thread that upserts them into the
catalogue, outside any request: a busy catalogue delays the catalogue, never a page or a control.
A catalogue that cannot be read (garbage, locked beyond its timeout, newer, unreachable) gives a
warning line with the table, and the runs of the directory read from the files.

Only files of the runs directory are read: a symbolic link that leads out of it, or a name that is
not UTF-8, is skipped (:func:`bench.catalog.rebuild.outside`, :func:`~bench.catalog.rebuild.unnameable`).
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

from bench.errors import BenchError, InputError

WRITE_RETRY_S = 5.0
"""Pause (s) of the cataloguer after a failed write before it tries again."""
READS_PER_REQUEST = 500
"""Run files one request reads at most (newest first; the rest at the next requests, as the
cataloguer takes them): a runs directory of thousands of uncatalogued files never makes one request
read them all."""


class RunsIndex:
    """The runs of ``runs_dir`` and of the catalogue ``catalog`` (URL or file, None: ``runs_dir/catalog.sqlite``)."""

    def __init__(self, runs_dir: Path, catalog: str | None):
        self.runs_dir = Path(runs_dir)
        self.catalog = catalog
        self._lock = threading.Lock()
        self._files: dict[str, tuple[tuple[int, int], dict[str, Any]]] = {}  # path -> ((mtime_ns, size), row)
        self._to_write: dict[str, dict[str, Any]] = {}
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.write_problem = ""
        """Why the last catalogue write failed (``""`` after a success)."""

    # ---- the request path: reads only ------------------------------------------------------------
    def table(self, f: Any) -> tuple[list[dict[str, Any]], list[str]]:
        """The rows of filter ``f`` (:class:`bench.catalog.query.RunFilter`, its ``limit`` the most
        rows), oldest start first, and warning lines. Never writes the catalogue."""
        import sqlalchemy as sa

        from bench.catalog.query import select_runs
        from bench.catalog.schema import runs
        from bench.catalog.store import open_catalog, resolve_url

        warnings: list[str] = []
        catalogued: list[dict[str, Any]] = []
        known: dict[str, str] | None = {}
        try:
            with open_catalog(resolve_url(self.catalog, self.runs_dir), create=False, writes=False) as cat:
                known = {r["path"]: r["status"] for r in cat.select(sa.select(runs.c.path, runs.c.status))}
                catalogued = cat.select(select_runs(f))
        except InputError as exc:
            if not exc.message.startswith("no catalogue at"):  # none yet: the cataloguer makes it
                known = None
                warnings.append(f"{exc.one_line()}; the runs below are read from the files of {self.runs_dir}")
        except BenchError as exc:
            known = None
            warnings.append(f"{exc}; the runs below are read from the files of {self.runs_dir}")
        fresh = self._file_rows(known)
        if self.write_problem and fresh:
            warnings.append(f"{len(fresh)} run file(s) not catalogued yet: {self.write_problem}")
        self._queue(fresh)
        rows = {r["path"]: r for r in catalogued}
        for path in fresh:
            rows.pop(path, None)  # the file says more than its catalogue row (or the row is not there yet)
        rows.update({r["path"]: r for r in _filtered(list(fresh.values()), f)})
        out = sorted(rows.values(), key=lambda r: (r["started_utc"] is not None, r["started_utc"] or 0, r["path"]))
        return (out[-f.limit:] if f.limit else out), warnings

    def _file_rows(self, known: dict[str, str] | None) -> dict[str, dict[str, Any]]:
        """The rows of the run files that ``known`` (catalogued path -> status; None: nothing is
        known) does not list or lists as running, read from the files (cached while unchanged)."""
        from bench.catalog.rebuild import outside, run_files, unnameable
        from bench.catalog.row import run_row
        from bench.record import layout

        if not self.runs_dir.is_dir():
            return {}
        out: dict[str, dict[str, Any]] = {}
        files = []
        for p in run_files(self.runs_dir, recursive=True):
            if outside(p, self.runs_dir) or unnameable(p):
                continue
            key = str(p.resolve())
            if known is not None and known.get(key, layout.STATUS_RUNNING) != layout.STATUS_RUNNING:
                continue
            try:
                st = p.stat()
            except OSError:
                continue
            files.append((st.st_mtime_ns, st.st_size, key, p))
        reads = 0
        for mtime_ns, size, key, p in sorted(files, reverse=True):  # newest first
            stamp = (mtime_ns, size)
            with self._lock:
                cached = self._files.get(key)
            if cached is not None and cached[0] == stamp:
                out[key] = cached[1]
                continue
            if reads >= READS_PER_REQUEST:
                continue
            reads += 1
            try:
                row = run_row(p)
            except (InputError, OSError):
                continue
            with self._lock:
                self._files[key] = (stamp, row)
            out[key] = row
        return out

    # ---- the cataloguer thread -------------------------------------------------------------------
    def _queue(self, rows: dict[str, dict[str, Any]]) -> None:
        with self._lock:
            for k, r in rows.items():
                if self._to_write.get(k) is not r:
                    self._to_write[k] = r
            if not self._to_write:
                return
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="bench-cataloguer", daemon=True)
                self._thread.start()
        self._wake.set()

    def _run(self) -> None:
        from bench.catalog.store import open_catalog, resolve_url

        while not self._stop.is_set():
            self._wake.wait()
            self._wake.clear()
            if self._stop.is_set():
                return
            with self._lock:
                batch, self._to_write = self._to_write, {}
            if not batch:
                continue
            try:
                with open_catalog(resolve_url(self.catalog, self.runs_dir)) as cat:
                    cat.upsert(list(batch.values()))
                self.write_problem = ""
            except Exception as exc:  # noqa: BLE001 - the catalogue's failure must not end the thread
                self.write_problem = str(exc) if isinstance(exc, BenchError) else f"{type(exc).__name__}: {exc}"
                with self._lock:
                    for k, r in batch.items():
                        self._to_write.setdefault(k, r)
                self._stop.wait(WRITE_RETRY_S)
                self._wake.set()

    def close(self) -> None:
        """Stop the cataloguer (its current write finishes)."""
        self._stop.set()
        self._wake.set()


def _filtered(rows: list[dict[str, Any]], f: Any) -> list[dict[str, Any]]:
    """``rows`` that filter ``f`` selects, by the catalogue's own SQL on an in-memory SQLite table."""
    if not rows:
        return []
    import sqlalchemy as sa

    from bench.catalog.query import select_runs
    from bench.catalog.schema import runs

    engine = sa.create_engine("sqlite://")
    try:
        with engine.begin() as conn:
            runs.create(conn)
            conn.execute(runs.insert(), rows)
            return [dict(r._mapping) for r in conn.execute(select_runs(f))]
    finally:
        engine.dispose()
