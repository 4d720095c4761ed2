"""Catalogue of runs: the unit query on 1 M rows, indexed vs a full scan, and the rebuild rate.

Part 1, per backend (SQLite file in WAL mode; PostgreSQL when available): bulk-insert ``--rows``
synthetic catalogue rows (``--serials`` unit serials interleaved through the table, so one serial's
rows are spread over the whole file), then time ``bench runs --unit SN``'s query path
(:func:`bench.catalog.query.find_runs`: the refresh of ``running`` rows, then the SELECT) for
``--queries`` different serials. Baseline in the same run: the same queries after dropping the
``(unit_serial, started_utc)`` index (a full scan), then the index is recreated.

Part 2: rebuild rate. ``--files`` small run files written with ``RunRecorder`` (a chamber monitor
stream of 600 rows, three checks, about 280 kB each) are catalogued with ``bench catalog rebuild``'s
:func:`bench.catalog.rebuild.rebuild`; baseline: :func:`bench.record.read_run_summary` of every
file alone (what any reader of those files pays).

    python benchmarks/bench_catalog.py [--rows 1000000] [--serials 1000] [--queries 20] [--files 200]
                                       [--postgres auto|none|URL] [--json]

``--postgres auto`` starts a throwaway server from Debian's ``postgresql`` package as the tests do
(``tests/test_catalog_postgres.py``) and skips PostgreSQL, saying why, when it cannot.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import sqlalchemy as sa

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench import __version__  # noqa: E402
from bench.catalog.query import RunFilter, find_runs  # noqa: E402
from bench.catalog.rebuild import rebuild, run_files  # noqa: E402
from bench.catalog.schema import runs  # noqa: E402
from bench.catalog.store import Catalog, open_catalog, resolve_url  # noqa: E402
from bench.record import Column, RunRecorder, layout, read_run_summary  # noqa: E402

UNIT_INDEX = "ix_runs_unit_started"
T0 = datetime(2026, 1, 1)


def synthetic_rows(n: int, serials: int) -> Iterator[dict[str, Any]]:
    """``n`` catalogue rows, serial ``SN{i % serials}``, one start per minute; streamed, never all in memory."""
    statuses = ("completed", "completed", "completed", "aborted", "crashed")
    verdicts = {"completed": "passed", "aborted": "incomplete", "crashed": "incomplete"}
    for i in range(n):
        status = statuses[i % len(statuses)]
        yield {
            "path": f"/data/runs/{i:08d}_procedure_{i % 11}.h5", "file_sha256": f"{i:064x}", "unit_serial": f"SN{i % serials:05d}",
            "unit_part": f"P-{i % 7}", "unit_revision": "A", "station": f"station-{i % 5}", "procedure_name": f"procedure_{i % 11}",
            "procedure_sha256": f"{i % 11:064x}", "operator": "ana", "mode": "hardware", "started_utc": T0 + timedelta(minutes=i),
            "ended_utc": T0 + timedelta(minutes=i, seconds=50), "run_time_s": 50.0, "status": status, "verdict": verdicts[status],
            "first_failed_check": None, "reason": "operator stop" if status == "aborted" else None,
            "min_pressure_torr": 10.0 ** -(i % 9) if i % 3 else None, "temp_min_degc": -30.0 + i % 50, "temp_max_degc": 40.0 + i % 30,
        }


def _analyze(cat: Catalog) -> None:
    with cat.transaction(write=True) as conn:
        conn.exec_driver_sql("ANALYZE")


def time_queries(cat: Catalog, serials: list[str]) -> tuple[float, int]:
    """Median wall time (s) of the unit query over ``serials`` and the rows of the first one."""
    times, counts = [], []
    for sn in serials:
        t0 = time.perf_counter()
        rows = find_runs(cat, RunFilter(unit=sn))
        times.append(time.perf_counter() - t0)
        counts.append(len(rows))
    assert len(set(counts)) == 1 and counts[0] > 0, counts
    return statistics.median(times), counts[0]


def bench_backend(url: str, n_rows: int, n_serials: int, n_queries: int) -> dict[str, Any]:
    """Bulk insert, then the unit query with and without its index."""
    out: dict[str, Any] = {}
    with open_catalog(resolve_url(url)) as cat:
        t0 = time.perf_counter()
        inserted = cat.insert_new(synthetic_rows(n_rows, n_serials))
        out["insert_s"] = time.perf_counter() - t0
        out["insert_rows_per_s"] = inserted / out["insert_s"]
        assert cat.count() == n_rows
        _analyze(cat)
        rng = np.random.default_rng(1)
        serials = [f"SN{k:05d}" for k in rng.choice(n_serials, size=n_queries, replace=False)]
        time_queries(cat, serials[:2])  # warm the caches both ways
        out["indexed_s"], out["rows_per_query"] = time_queries(cat, serials)
        with cat.transaction(write=True) as conn:
            conn.exec_driver_sql(f"DROP INDEX {UNIT_INDEX}")
        _analyze(cat)
        time_queries(cat, serials[:2])
        out["full_scan_s"], _ = time_queries(cat, serials)
        with cat.transaction(write=True) as conn:
            next(i for i in runs.indexes if i.name == UNIT_INDEX).create(conn)
        _analyze(cat)
        out["ratio_full_scan_over_indexed"] = out["full_scan_s"] / out["indexed_s"]
        if cat.backend == "sqlite":
            out["database_mb"] = Path(str(cat.url.database)).stat().st_size / 1e6
        else:
            with cat.transaction() as conn:
                out["database_mb"] = conn.execute(sa.text("SELECT pg_database_size(current_database())")).scalar() / 1e6
    return out


def write_run_files(directory: Path, n: int) -> None:
    """``n`` small, realistic run files: a chamber monitor stream (600 rows at 1 Hz: air
    temperature degC, pressure Torr) and three checks with limits, one failed in every 4th file."""
    t = np.arange(600.0)
    for i in range(n):
        rec = RunRecorder.create(directory, procedure_name=f"thermal_{i % 3}", procedure_text=f"schema: bench-procedure/1\n# {i}\n",
                                 procedure_path="-", config_text="-", config_path="-", mode="sim", software_version=__version__,
                                 started_utc=T0 + timedelta(minutes=i))
        key = rec.add_stream("tvac", [Column("air_temp", "degC"), Column("pressure", "Torr")], layout.MONITOR_STREAM)
        rec.start()
        rec.append(key, t, air_temp=20.0 + 0.05 * t, pressure=760.0 * np.exp(-t / 30.0))
        for step, name in enumerate(("bias_x", "bias_y", "bias_z")):
            outcome = "failed" if i % 4 == 0 and step == 2 else "passed"
            rec.event(layout.EVENT_STEP_START, "check", name, t_s=100.0 * step, step=step)
            rec.event("check", name, f"{outcome}: mean of acs_board.gyro.x = 0.1", t_s=100.0 * step + 50, step=step,
                      data=json.dumps({"name": name, "value": 0.1, "min": -1.0, "max": 1.0, "outcome": outcome}).encode())
            rec.event(layout.EVENT_STEP_END, "check", outcome, t_s=100.0 * step + 50, step=step)
        rec.close("completed")


def bench_rebuild(url: str, directory: Path) -> dict[str, Any]:
    """Rebuild rate (files/s) into an empty catalogue, and again (upserting unchanged rows)."""
    with open_catalog(resolve_url(url)) as cat:
        first = rebuild(cat, directory)
        again = rebuild(cat, directory)
        assert not first.unreadable and first.catalogued == first.files == again.catalogued
    return {"files": first.files, "rebuild_s": first.wall_s, "files_per_s": first.files_per_s,
            "rebuild_again_files_per_s": again.files_per_s}


def read_only_rate(directory: Path) -> float:
    """Baseline: files/s of :func:`read_run_summary` alone over the same files."""
    files = run_files(directory)
    t0 = time.perf_counter()
    for f in files:
        read_run_summary(f)
    return len(files) / (time.perf_counter() - t0)


def postgres(choice: str) -> tuple[Any, str, str]:
    """``(server to stop or None, URL prefix or "", why PostgreSQL is skipped or "")``."""
    if choice == "none":
        return None, "", "--postgres none"
    if choice != "auto":
        return None, choice.rstrip("/").rsplit("/", 1)[0], ""
    from tests.test_catalog_postgres import SERVER_USER, Server

    server = Server()
    why = server.start()
    if why:
        server.stop()
        return None, "", why
    return server, f"postgresql://{SERVER_USER}@127.0.0.1:{server.port}", ""


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=1_000_000, help="synthetic catalogue rows (default 1,000,000)")
    ap.add_argument("--serials", type=int, default=1000, help="distinct unit serials among them (default 1000)")
    ap.add_argument("--queries", type=int, default=20, help="unit queries timed each way; the median counts (default 20)")
    ap.add_argument("--files", type=int, default=200, help="small run files for the rebuild rate (default 200)")
    ap.add_argument("--postgres", default="auto", help="auto (throwaway server), none, or a server URL whose databases we may create")
    ap.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    args = ap.parse_args()
    result: dict[str, Any] = {"rows": args.rows, "serials": args.serials, "queries": args.queries, "sqlalchemy": sa.__version__}
    server, pg_prefix, pg_skipped = postgres(args.postgres)
    try:
        with tempfile.TemporaryDirectory(prefix="bench-catalog-") as tmp:
            backends = {"sqlite": lambda label: str(Path(tmp) / f"{label}.sqlite")}
            if pg_prefix:
                def pg_url(label: str) -> str:
                    import psycopg

                    with psycopg.connect(f"{pg_prefix}/postgres", connect_timeout=10, autocommit=True) as conn:
                        conn.execute(f'DROP DATABASE IF EXISTS "bench_catalog_{label}"')
                        conn.execute(f'CREATE DATABASE "bench_catalog_{label}"')
                    return f"{pg_prefix}/bench_catalog_{label}"
                backends["postgresql"] = pg_url
            else:
                result["postgresql_skipped"] = pg_skipped
            files_dir = Path(tmp) / "runs"
            files_dir.mkdir()
            write_run_files(files_dir, args.files)
            result["run_file_kb"] = sum(f.stat().st_size for f in files_dir.glob("*.h5")) / args.files / 1e3
            result["read_summary_files_per_s"] = read_only_rate(files_dir)
            for name, make in backends.items():
                result[name] = bench_backend(make("query"), args.rows, args.serials, args.queries)
                result[name]["rebuild"] = bench_rebuild(make("rebuild"), files_dir)
                result[name]["rebuild"]["ratio_over_read_summary"] = result[name]["rebuild"]["files_per_s"] / result["read_summary_files_per_s"]
    finally:
        if server is not None:
            server.stop()
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(f"{args.rows:,} rows, {args.serials} serials ({args.rows // args.serials} rows each); median of {args.queries} unit queries")
    for name in ("sqlite", "postgresql"):
        r = result.get(name)
        if r is None:
            print(f"  {name}: skipped ({result.get('postgresql_skipped', '')})")
            continue
        rb = r["rebuild"]
        print(f"  {name:10s} bulk insert {r['insert_s']:6.1f} s ({r['insert_rows_per_s']:,.0f} rows/s), {r['database_mb']:.0f} MB")
        print(f"  {'':10s} unit query indexed {r['indexed_s'] * 1e3:8.2f} ms, full scan {r['full_scan_s'] * 1e3:8.1f} ms "
              f"({r['rows_per_query']} rows): ratio {r['ratio_full_scan_over_indexed']:.0f}x")
        print(f"  {'':10s} rebuild {rb['files']} files of {result['run_file_kb']:.0f} kB: {rb['files_per_s']:.1f} files/s "
              f"(again: {rb['rebuild_again_files_per_s']:.1f}); read_run_summary alone {result['read_summary_files_per_s']:.1f} files/s "
              f"= {rb['ratio_over_read_summary']:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
