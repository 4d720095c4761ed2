"""The catalogue tests of ``tests/test_catalog.py`` against a real PostgreSQL server.

The session starts a throwaway server from Debian's ``postgresql`` package (``initdb`` and
``pg_ctl``; ``dev.py`` installs the package): a data directory in memory (``/dev/shm``, where it has
room; else in the system's temporary directory), trust
authentication, listening on 127.0.0.1 at a free port only (its socket in that directory), no
fsync. PostgreSQL refuses to run as root, so as root the server runs as ``nobody`` (``runuser``).
Every test gets a new database. When the server cannot be started the tests skip, saying why.
A pytest killed before its tear-down (SIGKILL, or SIGTERM, which pytest does not catch) leaves its
server running; the cluster's directory names the pytest that owns it (``owner.pid``), and the next
session stops and deletes the clusters whose owner is gone (:func:`reap_orphans`), so they do not
pile up (in ``/dev/shm`` they hold memory).
"""

from __future__ import annotations

import itertools
import os
import shutil
import socket
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Iterator

import pytest

from tests.programs import find_program
from tests.test_catalog import (  # noqa: F401 - collected here again, with the PostgreSQL ``backend`` below
    Backend,
    test_dry_runs_appear_with_status_and_verdict,
    test_killed_run_is_running_then_crashed_on_rebuild,
    test_queries_filter,
    test_rebuilt_catalogue_equals_the_live_one,
    test_unreadable_files_are_reported_and_the_rest_catalogued,
)

START_TIMEOUT_S = 60
"""Longest wait (s) for initdb, for the server to accept connections, and for it to stop."""
SERVER_USER = "bench"
"""The database superuser initdb creates (trust authentication on 127.0.0.1 only)."""


MEMORY_DIR = Path("/dev/shm")
MEMORY_DIR_MIN_FREE = 1 << 30
"""The server's data directory goes to the memory file system (``/dev/shm``) where it has this many
bytes free (a container's default 64 MiB does not), else to the system's temporary directory. The
session's databases grow to ~350 MB; on the disk, deleting them at the end of the session took
10-37 s on the shared 2-core machine (ext4 mounted with ``discard``), on ``/dev/shm`` no time."""


def _data_parent() -> str | None:
    """Where the throwaway cluster's directory is made (None: the system's temporary directory)."""
    try:
        if MEMORY_DIR.is_dir() and shutil.disk_usage(MEMORY_DIR).free >= MEMORY_DIR_MIN_FREE:
            return str(MEMORY_DIR)
    except OSError:
        pass
    return None


OWNER_FILE = "owner.pid"
"""In a cluster's directory: the process id of the pytest that made it."""


def _alive(pid: int) -> bool:
    """Whether process ``pid`` runs (a zombie, ended but not yet collected by its parent, does not)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process: alive
        pass
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return True


def reap_orphans(parents: list[Path], pg_ctl: str | None, as_user: list[str]) -> list[Path]:
    """Stop (``pg_ctl stop -m immediate``) and delete every ``bench-pg-*`` cluster under ``parents``
    whose owning pytest (``owner.pid``) is no longer running; returns the directories removed.
    A directory without an owner file, or whose owner is alive, is left alone."""
    removed = []
    for parent in parents:
        for root in sorted(parent.glob("bench-pg-*")) if parent.is_dir() else []:
            try:
                owner = int((root / OWNER_FILE).read_text().strip())
            except (OSError, ValueError):
                continue
            if owner == os.getpid() or _alive(owner):
                continue
            if pg_ctl and (root / "data" / "postmaster.pid").exists():
                subprocess.run([*as_user, pg_ctl, "-D", str(root / "data"), "-m", "immediate", "-w", "-t", "30", "stop"],
                               capture_output=True, timeout=60)
            shutil.rmtree(root, ignore_errors=True)
            if not root.exists():
                removed.append(root)
    return removed


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Server:
    """A throwaway PostgreSQL cluster in ``root`` (``start``, ``stop``); ``port`` on 127.0.0.1."""

    def __init__(self) -> None:
        self.initdb, self.pg_ctl = find_program("initdb"), find_program("pg_ctl")  # /usr/lib/postgresql/<major>/bin
        self.root = Path(tempfile.mkdtemp(prefix="bench-pg-", dir=_data_parent()))
        (self.root / OWNER_FILE).write_text(f"{os.getpid()}\n")
        self.data = self.root / "data"
        self.log = self.root / "server.log"
        self.port = _free_port()
        self.as_user: list[str] = []
        self.started = False

    def _run(self, *cmd: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([*self.as_user, *cmd], capture_output=True, text=True, timeout=START_TIMEOUT_S + 30)

    def start(self) -> str:
        """Start the cluster; returns "" or why it could not be started."""
        if not (self.initdb and self.pg_ctl):
            return "PostgreSQL server programs (initdb, pg_ctl) not found: install Debian's 'postgresql' package (dev.py does)"
        if os.geteuid() == 0:  # initdb and postgres refuse root
            runuser = find_program("runuser")  # /usr/sbin, off a PATH such as /usr/bin:/bin
            if runuser is None:
                return "running as root and 'runuser' is not available to start PostgreSQL as another user"
            self.as_user = [runuser, "-u", "nobody", "--"]
            shutil.chown(self.root, "nobody")
        reap_orphans([MEMORY_DIR, Path(tempfile.gettempdir())], self.pg_ctl, self.as_user)  # before this one starts
        r = self._run(self.initdb, "-D", str(self.data), "-U", SERVER_USER, "--auth=trust", "-E", "UTF8", "--no-sync")
        if r.returncode != 0:
            return f"initdb failed: {(r.stderr or r.stdout).strip().splitlines()[-1:]}"
        options = f"-p {self.port} -k {self.root} -c listen_addresses=127.0.0.1 -c fsync=off -c full_page_writes=off"
        r = self._run(self.pg_ctl, "-D", str(self.data), "-l", str(self.log), "-w", "-t", str(START_TIMEOUT_S), "-o", options, "start")
        if r.returncode != 0:
            tail = self.log.read_text(errors="replace").strip().splitlines()[-3:] if self.log.exists() else []
            return f"pg_ctl start failed: {(r.stderr or r.stdout).strip()} {tail}"
        self.started = True
        return ""

    def stop(self) -> None:
        if self.started:
            self._run(self.pg_ctl, "-D", str(self.data), "-m", "fast", "-w", "-t", str(START_TIMEOUT_S), "stop")
        shutil.rmtree(self.root, ignore_errors=True)

    def url(self, database: str) -> str:
        return f"postgresql://{SERVER_USER}@127.0.0.1:{self.port}/{database}"

    def create_database(self, name: str) -> str:
        """A new empty database; returns its URL."""
        import psycopg

        with psycopg.connect(host="127.0.0.1", port=self.port, user=SERVER_USER, dbname="postgres",
                             connect_timeout=10, autocommit=True) as conn:
            conn.execute(f'CREATE DATABASE "{name}"')
        return self.url(name)


@pytest.fixture(scope="session")
def pg_server() -> Iterator[Server]:
    server = Server()
    try:
        why = server.start()
        if why:
            print(f"\nPostgreSQL catalogue tests skipped: {why}")
            pytest.skip(why)
        yield server
    finally:
        server.stop()


_databases = itertools.count(1)


@pytest.fixture
def backend(pg_server: Server) -> Backend:
    """PostgreSQL: every catalogue a new database of the session's server."""
    def fresh(label: str) -> str:
        return pg_server.create_database(f"t{next(_databases)}_{label}")

    def live(_runs: Path) -> tuple[list[str], str]:
        url = fresh("live")
        return ["--catalog", url], url

    return Backend("postgresql", fresh, live)


def test_server_is_postgresql(pg_server: Server) -> None:
    """The tests above really ran against PostgreSQL, through the psycopg 3 driver."""
    from bench.catalog.store import open_catalog, resolve_url

    url = pg_server.create_database("probe")
    with open_catalog(resolve_url(url)) as cat, cat.transaction() as conn:
        assert cat.backend == "postgresql" and conn.dialect.driver == "psycopg"
        assert conn.exec_driver_sql("SHOW server_version").scalar().split(".")[0].isdigit()
        assert cat.version() == 1


def _ended_pid() -> int:
    """The process id of a process that has ended (free, until the system reuses it)."""
    p = subprocess.Popen(["true"])
    p.wait()
    return p.pid


def test_a_cluster_left_by_a_killed_session_is_stopped_and_deleted(pg_server: Server, tmp_path: Path) -> None:
    """A running cluster whose owning pytest is gone (as after ``kill -9``) is stopped and deleted by
    the next session's reaper; one whose owner runs, or that names no owner, is left alone."""
    orphan = Server()
    why = orphan.start()
    assert not why, why
    try:
        postmaster = int((orphan.data / "postmaster.pid").read_text().split()[0])
        assert _alive(postmaster)
        (orphan.root / OWNER_FILE).write_text(f"{_ended_pid()}\n")
        mine, unowned = tmp_path / "bench-pg-mine", tmp_path / "bench-pg-unowned"
        for d in (mine, unowned):
            (d / "data").mkdir(parents=True)
        (mine / OWNER_FILE).write_text(f"{os.getpid()}\n")
        assert reap_orphans([orphan.root.parent, tmp_path], orphan.pg_ctl, orphan.as_user) == [orphan.root]
        deadline = time.monotonic() + 30.0  # pg_ctl -w returns once the pid file is gone; the process ends just after
        while _alive(postmaster) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not orphan.root.exists() and not _alive(postmaster)
        assert mine.exists() and unowned.exists() and pg_server.root.exists()  # the session's own server kept
    finally:
        orphan.stop()
