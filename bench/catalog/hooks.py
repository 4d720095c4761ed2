"""Keeping a run's catalogue row up to date from the run path, without ever endangering the run.

``bench run`` (and ``bench soak``) call :meth:`RunCatalogHook.run_started` once the run file and the
lab are set up, and :meth:`RunCatalogHook.run_ended` once the file is closed and the lab is safe.
Both read the row from the run file itself (:func:`bench.catalog.row.run_row`, the code
``bench catalog rebuild`` uses, so the live catalogue and a rebuilt one agree) and upsert it.

A catalogue that cannot be reached, is locked beyond its timeout or fails in any other way costs
one warning line on stderr and nothing else: the run goes on and its file is complete;
``bench catalog rebuild RUNS_DIR`` adds the row later.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Callable

from bench.errors import BenchError


def warn_stderr(text: str) -> None:
    """Print a catalogue warning on stderr (never raises)."""
    try:
        print(f"bench: warning: {text}", file=sys.stderr, flush=True)
    except Exception:  # noqa: BLE001 - a closed stderr must not stop a run either
        pass


class RunCatalogHook:
    """The catalogue row of one run file (``path``) in the catalogue ``catalog`` (URL or file
    path; default ``runs_dir/catalog.sqlite``)."""

    def __init__(self, path: Path, runs_dir: Path, catalog: str | None = None,
                 warn: Callable[[str], None] = warn_stderr):
        self.path = Path(path)
        self.runs_dir = Path(runs_dir)
        self.catalog = catalog
        self.warn = warn
        self.ok: bool | None = None
        """Whether the last update reached the catalogue (None before the first)."""

    @classmethod
    def run_started(cls, path: Path, *, runs_dir: Path, catalog: str | None = None,
                    warn: Callable[[str], None] = warn_stderr) -> "RunCatalogHook":
        """Catalogue the run as ``running``; returns the hook for :meth:`run_ended`. Never raises."""
        hook = cls(path, runs_dir, catalog, warn)
        hook.update("start")
        return hook

    def run_ended(self) -> None:
        """Catalogue the run as its closed file says (status, verdict, hash, environment). Never raises."""
        self.update("end")

    def update(self, when: str) -> None:
        """Read the row from the file and upsert it; a failure is a warning (``when``: start | end)."""
        from bench.catalog.row import run_row
        from bench.catalog.store import display_url, open_catalog, resolve_url

        where = self.catalog or str(self.runs_dir)
        try:
            url = resolve_url(self.catalog, self.runs_dir)
            where = display_url(url)
            row = run_row(self.path)
            with open_catalog(url) as cat:
                cat.upsert([row])
            self.ok = True
        except Exception as exc:  # noqa: BLE001 - nothing the catalogue does may abort or lose a run
            self.ok = False
            reason = str(exc) if isinstance(exc, BenchError) else f"{type(exc).__name__}: {exc}"
            again = f"bench catalog rebuild {self.runs_dir}" + (f" --catalog {where}" if self.catalog else "")
            later = "" if "bench catalog rebuild" in reason else f"; '{again}' adds it later"  # else the reason says what to do
            self.warn(f"run {self.path.name} not catalogued at its {when} ({where}): {reason}; the run file is unaffected{later}")
