"""The catalogue of runs: one row per run file, in SQLite (embedded, next to the runs) or PostgreSQL
(shared by a lab), never the bulk data (see ``docs/catalog.md``).

* :mod:`~bench.catalog.schema`: the ``runs`` table and the versioned migrations;
* :mod:`~bench.catalog.store`: catalogue URLs, opening with bounded waits, upserts;
* :mod:`~bench.catalog.row`: a row computed from a run file (status, verdict, environment);
* :mod:`~bench.catalog.query`: the filters of ``bench runs``;
* :mod:`~bench.catalog.rebuild`: the catalogue rebuilt from the files;
* :mod:`~bench.catalog.hooks`: the row kept up to date at run start and run end.

Only :mod:`~bench.catalog.hooks` is imported by the run path, and it imports SQLAlchemy only when
it runs.
"""

from bench.catalog.hooks import RunCatalogHook

__all__ = ["RunCatalogHook"]
