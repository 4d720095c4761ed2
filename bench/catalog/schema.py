"""The catalogue's tables and their migrations: one schema for SQLite and PostgreSQL.

``runs`` holds one row per run file (never stream data, events or texts: those stay in the HDF5
file the row names). ``catalog_schema`` records every migration applied, newest last; the
catalogue's version is the highest one. :func:`migrate` brings a database to
:data:`SCHEMA_VERSION` inside one transaction, serialised between processes (SQLite: ``BEGIN
IMMEDIATE``, the database write lock; PostgreSQL: a transaction-level advisory lock), so two
stations opening a new shared catalogue at the same moment create it once. A database newer than
this bench knows is refused, never altered (the run-file ``format_version`` policy).

Why a version table of our own and not alembic: see ``docs/catalog.md`` ("Migrations").

Units: times are naive ``DateTime`` values in UTC (second resolution, as in the run file),
pressures in Torr, temperatures in degC, run times in s.
"""

from __future__ import annotations

from datetime import datetime, timezone
from typing import Callable

import sqlalchemy as sa
from sqlalchemy.engine import Connection

from bench.errors import BenchError

SCHEMA_VERSION = 1
"""Version of the catalogue schema this bench writes (the last entry of :data:`MIGRATIONS`)."""

PG_MIGRATION_LOCK = 0x62656E6368  # "bench": key of the PostgreSQL advisory lock held while migrating

metadata = sa.MetaData()

runs = sa.Table(
    "runs",
    metadata,
    sa.Column("path", sa.Text, primary_key=True, comment="absolute path of the run file (the key of every upsert)"),
    sa.Column("file_sha256", sa.Text, nullable=False, server_default="",
              comment="sha256 of the whole file once no process writes it (finalised or crashed); '' while running"),
    sa.Column("unit_serial", sa.Text, nullable=False, server_default="", comment="serial number of the unit under test"),
    sa.Column("unit_part", sa.Text, nullable=False, server_default="", comment="part number of the unit under test"),
    sa.Column("unit_revision", sa.Text, nullable=False, server_default="", comment="revision of the unit under test"),
    sa.Column("station", sa.Text, nullable=False, server_default="", comment="test station"),
    sa.Column("procedure_name", sa.Text, nullable=False, server_default=""),
    sa.Column("procedure_sha256", sa.Text, nullable=False, server_default="",
              comment="sha256 of the procedure text stored in the run file (utf-8 bytes)"),
    sa.Column("operator", sa.Text, nullable=False, server_default=""),
    sa.Column("mode", sa.Text, nullable=False, server_default="", comment="sim | hardware | replay | imported"),
    sa.Column("started_utc", sa.DateTime(timezone=False), nullable=True, comment="UTC"),
    sa.Column("ended_utc", sa.DateTime(timezone=False), nullable=True, comment="UTC; null until the file is closed"),
    sa.Column("run_time_s", sa.Double, nullable=True, comment="run time reached at the last flush, s"),
    sa.Column("status", sa.Text, nullable=False, comment="running | completed | aborted | failed | crashed (inferred)"),
    sa.Column("verdict", sa.Text, nullable=True, comment="passed | failed | no verdict | incomplete; null while running"),
    sa.Column("first_failed_check", sa.Text, nullable=True, comment="name of the first step that failed"),
    sa.Column("reason", sa.Text, nullable=True, comment="abort or error reason"),
    sa.Column("min_pressure_torr", sa.Double, nullable=True, comment="lowest pressure of the monitor streams, Torr"),
    sa.Column("temp_min_degc", sa.Double, nullable=True, comment="lowest temperature of the monitor streams, degC"),
    sa.Column("temp_max_degc", sa.Double, nullable=True, comment="highest temperature of the monitor streams, degC"),
)
sa.Index("ix_runs_unit_started", runs.c.unit_serial, runs.c.started_utc)
sa.Index("ix_runs_procedure_started", runs.c.procedure_name, runs.c.started_utc)
sa.Index("ix_runs_started", runs.c.started_utc)
sa.Index("ix_runs_status", runs.c.status)  # finds the few `running` rows every query refreshes

ROW_FIELDS: tuple[str, ...] = tuple(c.name for c in runs.columns)
"""Every column of ``runs``, in table order: the keys of a catalogue row."""

catalog_schema = sa.Table(
    "catalog_schema",
    metadata,
    sa.Column("version", sa.Integer, primary_key=True),
    sa.Column("applied_utc", sa.DateTime(timezone=False), nullable=False),
    sa.Column("software_version", sa.Text, nullable=False),
)


class CatalogError(BenchError):
    """The catalogue cannot be read or written (unreachable server, locked or newer database)."""


def _v1(conn: Connection) -> None:
    """Version 1: ``runs`` with its indexes. Frozen: a later change is a new migration, never an edit here."""
    runs.create(conn)


MIGRATIONS: tuple[Callable[[Connection], None], ...] = (_v1,)
"""``MIGRATIONS[i]`` takes a database from version ``i`` to ``i + 1``."""
assert len(MIGRATIONS) == SCHEMA_VERSION


def schema_version(conn: Connection) -> int:
    """The catalogue's version: 0 for an empty database."""
    if not sa.inspect(conn).has_table(catalog_schema.name):
        return 0
    return int(conn.execute(sa.select(sa.func.max(catalog_schema.c.version))).scalar() or 0)


def migrate(conn: Connection, software_version: str) -> int:
    """Apply the missing migrations on ``conn`` (inside its transaction, which the caller opened
    with the backend's write lock); returns the version found before. Raises :class:`CatalogError`
    for a database newer than :data:`SCHEMA_VERSION`."""
    if conn.dialect.name == "postgresql":
        conn.execute(sa.text("SELECT pg_advisory_xact_lock(:key)"), {"key": PG_MIGRATION_LOCK})
    found = schema_version(conn)
    if found > SCHEMA_VERSION:
        raise CatalogError(f"catalogue schema version {found} is newer than this bench knows (up to {SCHEMA_VERSION}); upgrade bench")
    if found == 0:
        catalog_schema.create(conn, checkfirst=True)
    for version in range(found, SCHEMA_VERSION):
        MIGRATIONS[version](conn)
        conn.execute(catalog_schema.insert().values(
            version=version + 1, applied_utc=datetime.now(timezone.utc).replace(tzinfo=None, microsecond=0),
            software_version=software_version))
    return found
