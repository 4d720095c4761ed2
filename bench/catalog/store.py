"""Opening a catalogue (SQLite file or PostgreSQL server) and writing and reading its rows.

:func:`resolve_url` turns what the user gave (nothing, a file path, ``sqlite:///PATH``,
``postgresql://USER@HOST[:PORT]/DB``) into a SQLAlchemy URL; :class:`Catalog` opens it with
bounded waits, brings the schema up to date (:func:`bench.catalog.schema.migrate`) and upserts
and selects rows with SQLAlchemy Core.

Every wait is bounded: SQLite waits at most :data:`SQLITE_BUSY_TIMEOUT_S` for the write lock,
PostgreSQL at most :data:`PG_CONNECT_TIMEOUT_S` to connect, :data:`PG_LOCK_TIMEOUT_MS` for a lock
and :data:`PG_STATEMENT_TIMEOUT_MS` per statement. Database failures become one-line
:class:`CatalogError` messages (the URL's password never appears).
"""

from __future__ import annotations

import re
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterable, Iterator, Mapping, Sequence

import sqlalchemy as sa
from sqlalchemy.engine import URL, Connection, Engine, make_url

from bench import __version__
from bench.catalog.schema import ROW_FIELDS, SCHEMA_VERSION, CatalogError, migrate, runs, schema_version
from bench.errors import InputError

CATALOG_FILE = "catalog.sqlite"
"""Name of the embedded catalogue next to the run files (``RUNS_DIR/catalog.sqlite``)."""

SQLITE_BUSY_TIMEOUT_S = 10.0
"""Longest wait (s) for another process's SQLite write transaction to end."""
PG_CONNECT_TIMEOUT_S = 5
"""Longest wait (s) to connect to a PostgreSQL server."""
PG_LOCK_TIMEOUT_MS = 10_000
"""Longest wait (ms) for a PostgreSQL lock (rows, tables, the migration lock)."""
PG_STATEMENT_TIMEOUT_MS = 120_000
"""Longest time (ms) one PostgreSQL statement may run."""
UPSERT_BATCH_ROWS = 1000
"""Rows per INSERT statement of a bulk upsert (both backends take at least this many parameters)."""

_SCHEMES = "postgresql://USER@HOST[:PORT]/DATABASE, sqlite:///PATH or a file path"


def resolve_url(catalog: str | None, runs_dir: Path | None = None, *, field: str = "--catalog") -> URL:
    """The SQLAlchemy URL of a catalogue: ``catalog`` when given (a URL or a file path), else
    ``runs_dir/catalog.sqlite``. ``postgresql://`` and ``postgres://`` use the psycopg 3 driver.
    Raises :class:`InputError` naming ``field`` for anything else."""
    if not catalog:
        if runs_dir is None:
            raise InputError("no catalogue given", None, field)
        return _sqlite_url(Path(runs_dir) / CATALOG_FILE)
    text = catalog.strip()
    if "://" not in text:
        return _sqlite_url(Path(text))
    try:
        url = make_url(text)
    except Exception as exc:  # noqa: BLE001 - SQLAlchemy raises ArgumentError and others for bad URLs
        raise InputError(f"cannot read catalogue URL {_redact(text)!r}: {exc}; expected {_SCHEMES}", None, field) from None
    backend = url.get_backend_name()
    if backend in ("postgresql", "postgres"):
        if not url.database:
            raise InputError(f"catalogue URL {display_url(url)!r} names no database; expected {_SCHEMES}", None, field)
        return url.set(drivername="postgresql+psycopg")
    if backend == "sqlite":
        if not url.database or url.database == ":memory:":
            raise InputError(f"catalogue URL {display_url(url)!r} names no file; expected {_SCHEMES}", None, field)
        return _sqlite_url(Path(url.database))
    raise InputError(f"unsupported catalogue backend {backend!r} in {display_url(url)!r}; expected {_SCHEMES}", None, field)


def _sqlite_url(path: Path) -> URL:
    return URL.create("sqlite", database=str(path.expanduser().resolve()))


def _redact(text: str) -> str:
    return re.sub(r"(://[^:/@]*:)[^@]*@", r"\1***@", text)


def display_url(url: URL) -> str:
    """The URL as messages show it: a SQLite catalogue as its file path, passwords hidden."""
    if url.get_backend_name() == "sqlite":
        return str(url.database)
    return url.set(drivername=url.get_backend_name()).render_as_string(hide_password=True)


def sqlite_file(url: URL) -> Path | None:
    """The file of a SQLite catalogue, None for a server."""
    return Path(url.database) if url.get_backend_name() == "sqlite" and url.database else None


def _engine(url: URL) -> Engine:
    if url.get_backend_name() == "sqlite":
        engine = sa.create_engine(url, connect_args={"timeout": SQLITE_BUSY_TIMEOUT_S})

        @sa.event.listens_for(engine, "connect")
        def _on_connect(dbapi_conn: Any, _record: Any) -> None:
            dbapi_conn.isolation_level = None  # transactions are begun below, not by the driver
            cur = dbapi_conn.cursor()
            cur.execute("PRAGMA journal_mode=WAL")  # readers never wait for the writer
            cur.execute("PRAGMA synchronous=NORMAL")  # WAL: durable at checkpoints, never corrupt
            cur.close()

        @sa.event.listens_for(engine, "begin")
        def _on_begin(conn: Connection) -> None:
            # writers take the lock at BEGIN, so a busy database is waited for (busy timeout)
            # instead of failing when a read transaction tries to become a write one
            conn.exec_driver_sql("BEGIN IMMEDIATE" if conn.get_execution_options().get("write") else "BEGIN")

        return engine
    options = f"-c lock_timeout={PG_LOCK_TIMEOUT_MS} -c statement_timeout={PG_STATEMENT_TIMEOUT_MS}"
    return sa.create_engine(url, pool_pre_ping=True,
                            connect_args={"connect_timeout": PG_CONNECT_TIMEOUT_S, "options": options,
                                          "application_name": "bench"})


def describe_db_error(exc: BaseException) -> str:
    """One line for a database failure: the driver's first line, without SQLAlchemy's background link."""
    orig = getattr(exc, "orig", None)
    text = str(orig if orig is not None else exc).strip()
    first = text.splitlines()[0] if text else type(exc).__name__
    return re.sub(r"\s*\(Background on this error at: [^)]*\)", "", first)


class Catalog:
    """An open catalogue. Use as a context manager (``with open_catalog(url) as cat``)."""

    def __init__(self, url: URL, engine: Engine):
        self.url = url
        self.engine = engine

    @property
    def backend(self) -> str:
        """``sqlite`` or ``postgresql``."""
        return self.engine.dialect.name

    def __enter__(self) -> "Catalog":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Close every pooled connection."""
        self.engine.dispose()

    @contextmanager
    def transaction(self, write: bool = False) -> Iterator[Connection]:
        """A transaction (committed on leaving the block); database errors become :class:`CatalogError`."""
        try:
            with self.engine.connect().execution_options(write=write) as conn, conn.begin():
                yield conn
        except sa.exc.SQLAlchemyError as exc:
            raise CatalogError(f"catalogue {display_url(self.url)}: {describe_db_error(exc)}") from None

    def upsert(self, rows: Sequence[Mapping[str, Any]]) -> int:
        """Insert ``rows`` or replace the rows with the same ``path``, in one transaction; returns
        how many were written. Each row has every field of :data:`ROW_FIELDS`."""
        if not rows:
            return 0
        with self.transaction(write=True) as conn:
            for i in range(0, len(rows), UPSERT_BATCH_ROWS):
                conn.execute(upsert_statement(conn), [dict(r) for r in rows[i : i + UPSERT_BATCH_ROWS]])
        return len(rows)

    def insert_new(self, rows: Iterable[Mapping[str, Any]]) -> int:
        """Plain bulk INSERT (no conflict handling), in batches of :data:`UPSERT_BATCH_ROWS`: for
        filling an empty catalogue fast (benchmarks). Returns the rows written."""
        n = 0
        with self.transaction(write=True) as conn:
            batch: list[Mapping[str, Any]] = []
            for r in rows:
                batch.append(r)
                if len(batch) >= UPSERT_BATCH_ROWS:
                    conn.execute(runs.insert(), batch)
                    n += len(batch)
                    batch = []
            if batch:
                conn.execute(runs.insert(), batch)
                n += len(batch)
        return n

    def select(self, stmt: sa.Select) -> list[dict[str, Any]]:
        """Rows of a SELECT on ``runs`` as dicts."""
        with self.transaction() as conn:
            return [dict(r._mapping) for r in conn.execute(stmt)]

    def count(self) -> int:
        """Rows in the catalogue."""
        with self.transaction() as conn:
            return int(conn.execute(sa.select(sa.func.count()).select_from(runs)).scalar() or 0)

    def version(self) -> int:
        """The schema version of the database."""
        with self.transaction() as conn:
            return schema_version(conn)


def upsert_statement(conn: Connection) -> Any:
    """``INSERT INTO runs ... ON CONFLICT (path) DO UPDATE SET <every other column> = excluded.<column>``
    in the dialect of ``conn`` (SQLite or PostgreSQL)."""
    if conn.dialect.name == "postgresql":
        from sqlalchemy.dialects.postgresql import insert
    else:
        from sqlalchemy.dialects.sqlite import insert
    stmt = insert(runs)
    return stmt.on_conflict_do_update(index_elements=[runs.c.path],
                                      set_={name: stmt.excluded[name] for name in ROW_FIELDS if name != "path"})


def open_catalog(url: URL, *, create: bool = True, field: str = "--catalog") -> Catalog:
    """Open the catalogue at ``url`` and bring its schema to the current version.

    ``create=False`` (queries) refuses a SQLite file that does not exist instead of creating an
    empty one: :class:`InputError` naming the option ``field`` that chose it. Raises
    :class:`CatalogError` when the database cannot be reached or migrated."""
    path = sqlite_file(url)
    if path is not None:
        if not create and not path.exists():
            raise InputError(f"no catalogue at {path}: build it with 'bench catalog rebuild {path.parent}'", None, field)
        if create and not path.parent.is_dir():
            raise CatalogError(f"catalogue {path}: directory {path.parent} does not exist")
    engine = _engine(url)
    cat = Catalog(url, engine)
    try:
        with cat.transaction() as conn:
            current = schema_version(conn) == SCHEMA_VERSION
        if not current:  # only then take the write lock
            with cat.transaction(write=True) as conn:
                migrate(conn, __version__)
    except BaseException:
        engine.dispose()
        raise
    return cat
