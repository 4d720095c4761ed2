"""Opening a catalogue (SQLite file or PostgreSQL server) and writing and reading its rows.

:func:`resolve_url` turns what the user gave (nothing, a file path, ``sqlite:///PATH``,
``postgresql://USER@HOST[:PORT]/DB``) into a SQLAlchemy URL; :class:`Catalog` opens it with
bounded waits, brings the schema up to date (:func:`bench.catalog.schema.migrate`) and upserts
and selects rows with SQLAlchemy Core.

Every wait is bounded: SQLite waits at most :data:`SQLITE_BUSY_TIMEOUT_S` for the write lock,
PostgreSQL at most :data:`PG_CONNECT_TIMEOUT_S` to connect, :data:`PG_LOCK_TIMEOUT_MS` for a lock
and :data:`PG_STATEMENT_TIMEOUT_MS` per statement. Database failures become one-line
:class:`CatalogError` messages (the URL's password never appears: :func:`bench.redact.redact`).

Nothing is written before the catalogue is known to be ours: a SQLite file is first checked to be
a SQLite database (else: move it aside, rebuild), then its schema version read without writing,
and only a version this bench knows is switched to WAL or migrated. A catalogue that cannot be
written (a read-only file system, a file of another user) is opened read-only: queries work,
writes fail with one line.
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
from bench.redact import redact
from bench.terminal_text import printable

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
SQLITE_HEADER = b"SQLite format 3\x00"
"""The first 16 bytes of every SQLite database file."""
PG_SSLMODES = ("disable", "allow", "prefer", "require", "verify-ca", "verify-full")
"""The values libpq accepts for ``sslmode``."""


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
    shown = printable(redact(text))
    if any(c in text for c in "\x00\r\n") or not text.isprintable():
        raise InputError(f"catalogue URL {shown!r} holds control characters", None, field)
    authority = text.split("://", 1)[1].split("/", 1)[0]
    if authority.count("@") > 1:
        raise InputError(f"catalogue URL {shown!r}: its user or password holds an '@': write it as %40 "
                         "(percent-encoded, as every special character of a URL password)", None, field)
    try:
        url = make_url(text)
        port = url.port
    except Exception as exc:  # noqa: BLE001 - SQLAlchemy raises ArgumentError, ValueError (a port that is no number)...
        raise InputError(f"cannot read catalogue URL {shown!r}: {printable(redact(str(exc)))}; expected {_SCHEMES}", None, field) from None
    backend = url.get_backend_name()
    if backend in ("postgresql", "postgres"):
        if not url.database:
            raise InputError(f"catalogue URL {display_url(url)!r} names no database; expected {_SCHEMES}", None, field)
        if port is not None and not 1 <= port <= 65535:
            raise InputError(f"catalogue URL {display_url(url)!r}: port {port} is not a TCP port (1..65535)", None, field)
        sslmode = url.query.get("sslmode")
        if sslmode is not None and sslmode not in PG_SSLMODES:
            raise InputError(f"catalogue URL {display_url(url)!r}: sslmode {printable(str(sslmode))!r} is not one of "
                             f"{', '.join(PG_SSLMODES)}", None, field)
        return url.set(drivername="postgresql+psycopg")
    if backend == "sqlite":
        if not url.database or url.database == ":memory:":
            raise InputError(f"catalogue URL {display_url(url)!r} names no file; expected {_SCHEMES}", None, field)
        return _sqlite_url(Path(url.database))
    raise InputError(f"unsupported catalogue backend {backend!r} in {display_url(url)!r}; expected {_SCHEMES}", None, field)


def _sqlite_url(path: Path) -> URL:
    return URL.create("sqlite", database=str(path.expanduser().resolve()))


def display_url(url: URL) -> str:
    """The URL as messages show it: a SQLite catalogue as its file path, passwords hidden."""
    if url.get_backend_name() == "sqlite":
        return str(url.database)
    return url.set(drivername=url.get_backend_name()).render_as_string(hide_password=True)


def sqlite_file(url: URL) -> Path | None:
    """The file of a SQLite catalogue, None for a server."""
    return Path(url.database) if url.get_backend_name() == "sqlite" and url.database else None


SQLITE_ACCESS = ("rw", "ro", "immutable")
"""How a SQLite catalogue is opened: read-write; read-only (``mode=ro``: a file this user cannot
write); read-only and unchanging (``immutable=1``: a WAL database on a read-only file system, where
SQLite cannot make the shared-memory file a read-only open needs)."""


def _sqlite_connect(path: str, access: str) -> Any:
    import sqlite3
    from urllib.parse import quote

    if access == "rw":
        return sqlite3.connect(path, timeout=SQLITE_BUSY_TIMEOUT_S, check_same_thread=False)
    query = "mode=ro" if access == "ro" else "mode=ro&immutable=1"
    return sqlite3.connect(f"file:{quote(path)}?{query}", uri=True, timeout=SQLITE_BUSY_TIMEOUT_S, check_same_thread=False)


def _engine(url: URL, access: str = "rw") -> Engine:
    if url.get_backend_name() == "sqlite":
        engine = sa.create_engine(url, creator=lambda: _sqlite_connect(str(url.database), access))

        @sa.event.listens_for(engine, "connect")
        def _on_connect(dbapi_conn: Any, _record: Any) -> None:
            dbapi_conn.isolation_level = None  # transactions are begun below, not by the driver
            cur = dbapi_conn.cursor()
            # WAL (readers never wait for the writer) is switched on once, by open_catalog, after the version check
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
    """One line for a database failure: the driver's first line, without SQLAlchemy's background
    link, credentials or control characters."""
    orig = getattr(exc, "orig", None)
    text = str(orig if orig is not None else exc).strip()
    first = text.splitlines()[0] if text else type(exc).__name__
    return printable(redact(re.sub(r"\s*\(Background on this error at: [^)]*\)", "", first)))


_NOT_OURS = ("file is not a database", "database disk image is malformed")
"""SQLite's words for a file it cannot read as a database."""


def move_aside_hint(path: Path) -> str:
    """What to do with a catalogue file that is not a database: it is an index of the run files, so
    moving it aside and rebuilding loses nothing."""
    return (f"move it aside (mv {path} {path}.broken) and run 'bench catalog rebuild {path.parent}' "
            "to make a new one from the run files")


def _check_sqlite_file(path: Path) -> None:
    """Refuse a SQLite catalogue file that is not a SQLite database (garbage, another program's
    file) before SQLite touches it; an empty file is a new database."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(len(SQLITE_HEADER))
    except FileNotFoundError:
        return
    except OSError as exc:
        raise CatalogError(f"catalogue {path}: cannot be read: {exc.strerror or exc}") from None
    if head and head != SQLITE_HEADER:
        raise CatalogError(f"catalogue {path} is not a SQLite database; {move_aside_hint(path)}")


class Catalog:
    """An open catalogue. Use as a context manager (``with open_catalog(url) as cat``)."""

    def __init__(self, url: URL, engine: Engine, read_only: bool = False):
        self.url = url
        self.engine = engine
        self.read_only = read_only
        """True when the catalogue could only be opened for reading (queries work, writes raise)."""

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
        if write and self.read_only:
            raise CatalogError(f"catalogue {display_url(self.url)} is read-only here (a read-only file system, or a file "
                               "this user cannot write): it can be queried, not written")
        try:
            with self.engine.connect().execution_options(write=write) as conn, conn.begin():
                yield conn
        except sa.exc.SQLAlchemyError as exc:
            reason = describe_db_error(exc)
            path = sqlite_file(self.url)
            if path is not None and any(w in reason for w in _NOT_OURS):
                reason += f"; {move_aside_hint(path)}"
            raise CatalogError(f"catalogue {display_url(self.url)}: {reason}") from None

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


def open_catalog(url: URL, *, create: bool = True, field: str = "--catalog", writes: bool = True) -> Catalog:
    """Open the catalogue at ``url`` and bring its schema to the current version.

    ``create=False`` (queries) refuses a SQLite file that does not exist instead of creating an
    empty one: :class:`InputError` naming the option ``field`` that chose it. ``writes=False``
    (the web station's requests) writes nothing at all: no WAL switch, no migration (a catalogue of
    another version is then a :class:`CatalogError`). Raises :class:`CatalogError` when the database
    cannot be reached or migrated."""
    path = sqlite_file(url)
    if path is not None:
        if not create and not path.exists():
            raise InputError(f"no catalogue at {path}: build it with 'bench catalog rebuild {path.parent}'", None, field)
        if create and not path.parent.is_dir():
            raise CatalogError(f"catalogue {path}: directory {path.parent} does not exist")
        _check_sqlite_file(path)
    for access in SQLITE_ACCESS if path is not None else ("rw",):
        cat = Catalog(url, _engine(url, access), read_only=access != "rw")
        try:
            with cat.transaction() as conn:  # reads only: nothing is written before the version is known
                found = schema_version(conn)
            break
        except CatalogError as exc:
            cat.close()
            cannot_write = "unable to open database file" in str(exc) or "readonly" in str(exc)
            if path is None or access == SQLITE_ACCESS[-1] or not cannot_write or not path.is_file():
                raise
    try:
        if found > SCHEMA_VERSION:  # refused before anything is written (the run-file format_version policy)
            raise CatalogError(f"catalogue schema version {found} is newer than this bench knows (up to {SCHEMA_VERSION}); "
                               f"upgrade bench ({display_url(url)} was left as it is)")
        if path is not None and not cat.read_only and writes:
            cat.read_only = not _sqlite_wal(cat.engine)
        if found != SCHEMA_VERSION:  # only then take the write lock
            if not writes:
                raise CatalogError(f"catalogue {display_url(url)} has schema version {found}, not {SCHEMA_VERSION} yet")
            if cat.read_only:
                raise CatalogError(f"catalogue {display_url(url)} has schema version {found} and is read-only here: "
                                   "it cannot be brought to this bench's version")
            with cat.transaction(write=True) as conn:
                migrate(conn, __version__)
    except BaseException:
        cat.close()
        raise
    return cat


def _sqlite_wal(engine: Engine) -> bool:
    """Switch a SQLite catalogue to WAL (readers never wait for the writer; kept in the file, so
    once is enough). False when the file cannot be written (then it is used read-only)."""
    raw = engine.raw_connection()
    try:
        cur = raw.cursor()
        mode = cur.execute("PRAGMA journal_mode").fetchone()[0]
        if str(mode).lower() != "wal":
            cur.execute("PRAGMA journal_mode=WAL")
        cur.close()
        return True
    except Exception as exc:  # noqa: BLE001 - sqlite3.OperationalError
        if "readonly" in str(exc) or "read-only" in str(exc):
            return False
        raise CatalogError(f"catalogue {engine.url.database}: {describe_db_error(exc)}") from None
    finally:
        raw.close()
