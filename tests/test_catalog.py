"""The catalogue of runs (docs/catalog.md): dry-runs catalogued live with status and verdict, the
catalogue rebuilt from the files equal to the live one, a killed run, unreadable files, queries.

The tests that take the ``backend`` fixture run here against SQLite and, in
``tests/test_catalog_postgres.py``, against a real PostgreSQL server (same tests, other fixture).
"""

from __future__ import annotations

import re

import hashlib
import json
import shutil
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any, Callable

import pytest

from bench.catalog.query import RunFilter, refresh_running, select_runs
from bench.catalog.rebuild import rebuild
from bench.catalog.schema import ROW_FIELDS, CatalogError, catalog_schema
from bench.catalog.store import CATALOG_FILE, open_catalog, resolve_url
from bench.cli import main
from bench.errors import InputError
from bench.record import read_run_summary
from bench.record.reader import STALE_AFTER_S
from tests.conftest import ROOT, SIM_CONFIG, write_procedure


@dataclass
class Backend:
    """A catalogue backend for the tests: ``fresh(label)`` gives the URL of a new empty catalogue;
    ``live(runs_dir)`` the ``bench run`` options and URL of the catalogue runs write to."""

    name: str
    fresh: Callable[[str], str]
    live: Callable[[Path], tuple[list[str], str]]


@pytest.fixture
def backend(tmp_path: Path) -> Backend:
    """SQLite: the default catalogue next to the runs, other catalogues as files."""
    return Backend("sqlite", lambda label: str(tmp_path / f"{label}.sqlite"),
                   lambda runs: ([], str(runs / CATALOG_FILE)))


# ---- helpers ------------------------------------------------------------------------------------
VAC_STEPS = """\
  - power: {{instrument: acs_board, on: true}}
  - pump_down: {{instrument: tvac, pressure: 1e-3 Torr, timeout: {timeout}}}
  - record: {{instrument: acs_board, duration: 20 s, window: still}}
  - check: {{name: bias_z, signal: acs_board.gyro.z, statistic: mean, window: still, min: {lo}, max: {hi}}}
"""


def rows_of(url: str) -> list[dict[str, Any]]:
    """Every row of the catalogue at ``url``, in start order."""
    with open_catalog(resolve_url(url), create=False) as cat:
        return cat.select(select_runs(RunFilter()))


def cli_json(capsys: pytest.CaptureFixture[str], *args: str) -> list[dict[str, Any]]:
    capsys.readouterr()
    code = main(["runs", *args, "--json"])
    out = capsys.readouterr()
    assert code == 0, out.err
    return json.loads(out.out)


def sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


@dataclass
class DryRuns:
    runs: Path
    url: str
    procedures: dict[str, Path]
    codes: dict[str, int]


def dry_runs(tmp_path: Path, backend: Backend) -> DryRuns:
    """Four short dry-runs on configs/sim.yaml, catalogued live: passed, failed, no verdict, aborted."""
    runs = tmp_path / "runs"
    opts, url = backend.live(runs)
    procs = {
        "vac_pass": write_procedure(tmp_path / "vac_pass.yaml", VAC_STEPS.format(timeout="2 h", lo="-1 deg/s", hi="1 deg/s"), "[acs_board, tvac]"),
        "vac_fail": write_procedure(tmp_path / "vac_fail.yaml", VAC_STEPS.format(timeout="2 h", lo="5 deg/s", hi="6 deg/s"), "[acs_board, tvac]"),
        "vac_abort": write_procedure(tmp_path / "vac_abort.yaml", VAC_STEPS.format(timeout="30 s", lo="-1 deg/s", hi="1 deg/s").replace("1e-3 Torr", "1e-9 Torr"),
                                     "[acs_board, tvac]"),
        "board_only": write_procedure(tmp_path / "board_only.yaml", "  - power: {instrument: acs_board, on: true}\n"
                                      "  - record: {instrument: acs_board, duration: 5 s, window: w}\n"
                                      "  - check: {name: mean_z, signal: acs_board.gyro.z, statistic: mean, window: w}\n"),
    }
    units = {"vac_pass": ["--unit", "SN12", "--part", "P-100", "--revision", "B"], "vac_fail": ["--unit", "SN12", "--part", "P-100"],
             "vac_abort": ["--unit", "SN12"], "board_only": ["--unit", "SN7"]}
    codes = {name: main(["run", str(p), "--config", str(SIM_CONFIG), "--sim", "--runs-dir", str(runs), *units[name], *opts])
             for name, p in procs.items()}
    return DryRuns(runs, url, procs, codes)


# ---- dry-runs catalogued live -------------------------------------------------------------------
def test_dry_runs_appear_with_status_and_verdict(tmp_path: Path, backend: Backend, capsys: pytest.CaptureFixture[str]) -> None:
    d = dry_runs(tmp_path, backend)
    assert d.codes == {"vac_pass": 0, "vac_fail": 1, "vac_abort": 1, "board_only": 0}
    assert "not catalogued" not in capsys.readouterr().err
    args = ["--catalog", d.url] if backend.name != "sqlite" else ["--runs-dir", str(d.runs)]
    rows = {r["procedure_name"]: r for r in cli_json(capsys, *args)}
    assert set(rows) == set(d.procedures)
    for name, r in rows.items():
        assert set(r) == set(ROW_FIELDS)
        path = Path(r["path"])
        assert path.parent == d.runs.resolve() and path.name.endswith(f"_{name}.h5")
        assert r["file_sha256"] == sha256(path)  # finalised: the hash of the file as it is
        assert r["procedure_sha256"] == sha256(d.procedures[name])  # the procedure text stored in the file
        assert r["mode"] == "sim" and r["operator"] and r["station"]
        assert r["started_utc"].endswith("Z") and r["ended_utc"] >= r["started_utc"]

    p = rows["vac_pass"]
    assert (p["status"], p["verdict"], p["first_failed_check"], p["reason"]) == ("completed", "passed", None, None)
    assert (p["unit_serial"], p["unit_part"], p["unit_revision"]) == ("SN12", "P-100", "B")
    assert 0 < p["min_pressure_torr"] <= 1e-3  # pumped down to 1e-3 Torr: the chamber's monitor stream
    assert p["temp_min_degc"] <= p["temp_max_degc"] and 10 < p["temp_min_degc"] < 30  # chamber at room temperature
    f = rows["vac_fail"]
    assert (f["status"], f["verdict"], f["first_failed_check"]) == ("completed", "failed", "bias_z")
    a = rows["vac_abort"]
    assert (a["status"], a["verdict"]) == ("aborted", "incomplete")
    assert "pressure did not fall" in a["reason"]
    b = rows["board_only"]
    assert (b["status"], b["verdict"], b["unit_serial"]) == ("completed", "no verdict", "SN7")
    # no chamber, no thermocouples: nothing measured, nothing invented
    assert (b["min_pressure_torr"], b["temp_min_degc"], b["temp_max_degc"]) == (None, None, None)

    assert [r["procedure_name"] for r in cli_json(capsys, *args, "--unit", "SN12", "--verdict", "failed")] == ["vac_fail"]
    assert {r["procedure_name"] for r in cli_json(capsys, *args, "--unit", "SN12", "--vacuum-below", "1e-3 Torr")} == {"vac_pass", "vac_fail"}


def test_rebuilt_catalogue_equals_the_live_one(tmp_path: Path, backend: Backend, capsys: pytest.CaptureFixture[str]) -> None:
    d = dry_runs(tmp_path, backend)
    live = rows_of(d.url)
    assert len(live) == 4
    rebuilt_url = backend.fresh("rebuilt")
    capsys.readouterr()
    assert main(["catalog", "rebuild", str(d.runs), "--catalog", rebuilt_url]) == 0
    out = capsys.readouterr().out
    assert "catalogued 4 of 4 run file(s)" in out and "files/s" in out and "0 unreadable" in out
    assert rows_of(rebuilt_url) == live
    # idempotent: again into the same catalogue, and into the live one itself
    assert main(["catalog", "rebuild", str(d.runs), "--catalog", rebuilt_url]) == 0
    assert main(["catalog", "rebuild", str(d.runs), "--catalog", d.url]) == 0
    assert rows_of(rebuilt_url) == live == rows_of(d.url)


# ---- a run killed mid-way -----------------------------------------------------------------------
def _wait(what: str, probe: Callable[[], Any], timeout_s: float = 60.0) -> Any:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            value = probe()
        except (InputError, CatalogError, OSError):
            value = None
        if value:
            return value
        time.sleep(0.1)
    raise AssertionError(f"{what} within {timeout_s} s")


def test_killed_run_is_running_then_crashed_on_rebuild(tmp_path: Path, backend: Backend) -> None:
    runs = tmp_path / "runs"
    opts, url = backend.live(runs)
    proc = write_procedure(tmp_path / "stationary.yaml", "  - power: {instrument: acs_board, on: true}\n"
                           "  - record: {instrument: acs_board, duration: 60 s}\n")
    p = subprocess.Popen([sys.executable, "-m", "bench", "run", str(proc), "--config", str(SIM_CONFIG), "--sim", "--realtime",
                          "--runs-dir", str(runs), "--unit", "SN3", *opts], cwd=ROOT,
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        (row,) = _wait("a running row in the live catalogue", lambda: rows_of(url))
        path = Path(row["path"])
        assert (row["status"], row["verdict"], row["file_sha256"], row["unit_serial"]) == ("running", None, "", "SN3")
        # (until the recording starts the name holds the run's placeholder, without streams: issue 31, D5)
        _wait("rows recorded", lambda: any(s.rows >= 100 for s in read_run_summary(path).streams))
        p.send_signal(signal.SIGKILL)
        p.wait(timeout=10)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait(timeout=10)
    assert [r["status"] for r in rows_of(url)] == ["running"]  # nobody told the catalogue

    later = time.time() + STALE_AFTER_S + 1  # as the reader will see it once the heartbeat is stale
    rebuilt_url = backend.fresh("rebuilt")
    with open_catalog(resolve_url(rebuilt_url)) as cat:
        report = rebuild(cat, runs, now_unix=later)
    assert (report.files, report.catalogued, report.unreadable) == (1, 1, [])
    (crashed,) = rows_of(rebuilt_url)
    assert (crashed["status"], crashed["verdict"], crashed["unit_serial"]) == ("crashed", "incomplete", "SN3")
    assert crashed["reason"].startswith("writer stopped: no heartbeat since ")
    assert crashed["file_sha256"] == sha256(path) and crashed["run_time_s"] > 0
    # a query refreshes the live row the same way, and then both catalogues agree
    with open_catalog(resolve_url(url)) as cat:
        assert refresh_running(cat, now_unix=later) == 1
    assert rows_of(url) == rows_of(rebuilt_url)


# ---- unreadable files ---------------------------------------------------------------------------
def test_unreadable_files_are_reported_and_the_rest_catalogued(tmp_path: Path, backend: Backend,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    runs = tmp_path / "runs"
    proc = write_procedure(tmp_path / "short.yaml", "  - power: {instrument: acs_board, on: true}\n"
                           "  - record: {instrument: acs_board, duration: 2 s}\n")
    for _ in range(2):
        assert main(["run", str(proc), "--config", str(SIM_CONFIG), "--sim", "--runs-dir", str(runs)]) == 0
    good = sorted(runs.glob("*.h5"))
    (runs / "0_garbage.h5").write_bytes(b"not an HDF5 file at all\n" * 10)
    truncated = runs / "1_truncated.h5"
    truncated.write_bytes(good[0].read_bytes()[:2000])
    other = runs / "2_empty.h5"
    other.write_bytes(b"")
    url = backend.fresh("rebuilt")
    capsys.readouterr()
    assert main(["catalog", "rebuild", str(runs), "--catalog", url]) == 1
    out = capsys.readouterr()
    assert "Traceback" not in out.err
    bad_lines = [line for line in out.err.splitlines() if "not a readable bench run file" in line]
    assert sorted(line.split(":", 1)[0] for line in bad_lines) == sorted(str(runs / n) for n in ("0_garbage.h5", "1_truncated.h5", "2_empty.h5"))
    assert "catalogued 2 of 5 run file(s)" in out.out and "3 unreadable" in out.out
    assert sorted(Path(r["path"]) for r in rows_of(url)) == [g.resolve() for g in good]


# ---- queries ------------------------------------------------------------------------------------
NOW = datetime.now(timezone.utc).replace(tzinfo=None, microsecond=0)


def synthetic_rows() -> list[dict[str, Any]]:
    """24 rows over 12 days, every filter value several times; two with NULL pressure."""
    procs = ["thermal_ramp_vacuum", "thermal_ramp_ambient", "allan_static", "allan%static"]
    statuses = ["completed", "completed", "aborted", "crashed", "running", "failed"]
    verdicts = {"completed": ["passed", "failed", "no verdict"], "aborted": ["incomplete"], "crashed": ["incomplete"],
                "running": [None], "failed": ["failed"]}
    rows = []
    for i in range(24):
        status = statuses[i % len(statuses)]
        rows.append({
            "path": f"/nonexistent/runs/{i:02d}.h5", "file_sha256": "" if status == "running" else f"{i:064x}",
            "unit_serial": f"SN{i % 3 + 1}", "unit_part": "P-100" if i % 2 else "P-200", "unit_revision": "A",
            "station": "tvac-1" if i % 4 < 2 else "rt-2", "procedure_name": procs[i % 4], "procedure_sha256": f"{i % 4:064x}",
            "operator": "ana", "mode": "sim" if i % 5 in (1, 2) else "hardware", "started_utc": NOW - timedelta(hours=12 * (24 - i)),
            "ended_utc": None if status == "running" else NOW - timedelta(hours=12 * (24 - i) - 1), "run_time_s": 3600.0,
            "status": status, "verdict": verdicts[status][(i // len(statuses)) % len(verdicts[status])],
            "first_failed_check": "bias_z" if i % 5 == 0 else None, "reason": "operator stop" if status == "aborted" else None,
            "min_pressure_torr": None if i % 7 == 3 else 10.0 ** -(i % 8), "temp_min_degc": -30.0 + i, "temp_max_degc": 60.0 - i,
        })
    return rows


FILTERS: list[tuple[list[str], Callable[[dict[str, Any]], bool]]] = [
    ([], lambda r: True),
    (["--unit", "SN2"], lambda r: r["unit_serial"] == "SN2"),
    (["--unit", "SN2", "--verdict", "failed"], lambda r: r["unit_serial"] == "SN2" and r["verdict"] == "failed"),
    (["--unit", "SN*"], lambda r: True),
    (["--part", "P-100"], lambda r: r["unit_part"] == "P-100"),
    (["--procedure", "thermal_*"], lambda r: r["procedure_name"].startswith("thermal_")),
    (["--procedure", "allan_static"], lambda r: r["procedure_name"] == "allan_static"),  # '_' is no wildcard
    (["--procedure", "allan%*"], lambda r: r["procedure_name"] == "allan%static"),  # nor '%'
    (["--station", "rt-2", "--status", "completed"], lambda r: r["station"] == "rt-2" and r["status"] == "completed"),
    (["--status", "crashed"], lambda r: r["status"] == "crashed"),
    (["--verdict", "no-verdict"], lambda r: r["verdict"] == "no verdict"),
    (["--verdict", "incomplete", "--unit", "SN1"], lambda r: r["verdict"] == "incomplete" and r["unit_serial"] == "SN1"),
    (["--since", (NOW - timedelta(days=3)).strftime("%Y-%m-%dT%H:%M:%SZ")], lambda r: r["started_utc"] >= NOW - timedelta(days=3)),
    (["--since", "100 h"], lambda r: r["started_utc"] >= NOW - timedelta(hours=100, seconds=60)),
    (["--vacuum-below", "1e-4 Torr"], lambda r: r["min_pressure_torr"] is not None and r["min_pressure_torr"] <= 1e-4),
    (["--vacuum-below", "1.4e-2 mbar"], lambda r: r["min_pressure_torr"] is not None and r["min_pressure_torr"] <= 1.4e-2 * 0.750062),
    (["--unit", "SN3", "--limit", "3"], lambda r: r["unit_serial"] == "SN3"),
    (["--mode", "dry-run"], lambda r: r["mode"] == "sim"),  # issue 30: dry-runs apart from real runs
    (["--mode", "real", "--verdict", "passed"], lambda r: r["mode"] == "hardware" and r["verdict"] == "passed"),
    (["--mode", "sim", "--verdict", "passed"], lambda r: r["mode"] == "sim" and r["verdict"] == "passed"),
]


@pytest.mark.parametrize("args, keep", FILTERS, ids=[" ".join(a) or "all" for a, _ in FILTERS])
def test_queries_filter(tmp_path: Path, backend: Backend, capsys: pytest.CaptureFixture[str], args: list[str],
                        keep: Callable[[dict[str, Any]], bool]) -> None:
    url = backend.fresh("q")
    rows = synthetic_rows()
    with open_catalog(resolve_url(url)) as cat:
        cat.upsert([{**r, "status": "completed", "verdict": "passed"} for r in rows])
        cat.upsert(rows)  # the same paths again: replaced, not added
        assert cat.count() == len(rows)
    expected = sorted((r for r in rows if keep(r)), key=lambda r: (r["started_utc"], r["path"]))
    if "--limit" in args:
        expected = expected[-int(args[args.index("--limit") + 1]):]  # the latest ones, still oldest first
    got = cli_json(capsys, "--catalog", url, *args)
    assert [g["path"] for g in got] == [e["path"] for e in expected]
    assert expected, "a filter that keeps nothing tests nothing"
    if got:
        first = expected[0]
        assert got[0]["started_utc"] == first["started_utc"].strftime("%Y-%m-%dT%H:%M:%SZ")
        assert got[0]["min_pressure_torr"] == first["min_pressure_torr"] and got[0]["verdict"] == first["verdict"]


# ---- SQLite only: the command line, the run path ---------------------------------------------------
@pytest.mark.parametrize("args, field", [
    (["--since", "yesterday-ish"], "--since"), (["--since", "7"], "--since"), (["--since", "-2 d"], "--since"),
    (["--since", "3 kg"], "--since"), (["--status", "done"], "--status"), (["--verdict", "maybe"], "--verdict"),
    (["--unit", " "], "--unit"), (["--vacuum-below", "-1 Torr"], "--vacuum-below"), (["--vacuum-below", "3 s"], "--vacuum-below"),
    (["--limit", "0"], "--limit"), (["--catalog", "mysql://u@h/db"], "--catalog"), (["--catalog", "postgresql://u@h"], "--catalog"),
])
def test_bad_filter_values_exit_2_located(tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], field: str) -> None:
    assert main(["catalog", "rebuild", str(tmp_path)]) == 0  # an empty catalogue exists: only the value is wrong
    capsys.readouterr()
    assert main(["runs", "--runs-dir", str(tmp_path), *args]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and err.startswith(f"{field}: "), err


def test_missing_catalogue_and_directory_are_bad_input(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["runs", "--runs-dir", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("--runs-dir: no catalogue at ") and "bench catalog rebuild" in err
    assert not (tmp_path / CATALOG_FILE).exists()  # a query never creates an empty catalogue
    assert main(["catalog", "rebuild", str(tmp_path / "nope")]) == 2
    assert capsys.readouterr().err.startswith("DIR: ")


def test_table_fits_80_columns(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    url = str(tmp_path / "c.sqlite")
    rows = synthetic_rows()
    rows[0]["procedure_name"] = "a_procedure_name_much_longer_than_the_table_has_room_for"
    with open_catalog(resolve_url(url)) as cat:
        cat.upsert(rows)
    capsys.readouterr()
    assert main(["runs", "--catalog", url]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert max(len(line) for line in lines) <= 80, "\n".join(lines)
    long = rows[0]["procedure_name"]  # whole, continued over lines, never cut to "…"
    col, end = lines[0].index("procedure"), lines[0].index("mode")
    pieces = [line[col:end].strip() for line in lines[1:6]]
    assert "…" not in "".join(lines) and any("".join(pieces[:k]) == long for k in range(2, 6)), pieces
    # the environment did not fit beside the names: it is in the notes, with its units
    assert any(re.fullmatch(r"\s+\d+ p min \S+ Torr, T \S+ \.\. \S+ degC", line) for line in lines), "\n".join(lines)
    assert lines[-4:-1] == [f"{len(rows)} run(s):", "  real     14: 3 passed, 2 failed, 1 no verdict, 6 incomplete, 2 running",
                            "  DRY-RUN  10: 1 passed, 4 failed, 1 no verdict, 2 incomplete, 2 running"]
    assert lines[-1].startswith("DRY-RUN: not acceptance evidence")
    assert any("first failed: bias_z" in line for line in lines) and any("aborted: operator stop" in line for line in lines)


def test_runs_tell_a_dry_run_from_a_real_run_at_80_columns(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 30 item 1: `bench runs --verdict passed` listed dry-runs as plain passes, with no mode
    column, and printed 760 Torr as 7.6e+02. Each row now names its mode (DRY-RUN for a simulated
    run), the summary counts verdicts per mode, pressures read 760 and 1e-05."""
    url = str(tmp_path / "c.sqlite")
    rows = [r for r in synthetic_rows() if r["verdict"] == "passed"][:4]
    for r, (mode, p) in zip(rows, (("hardware", 760.0), ("sim", 760.0), ("sim", 1e-5), ("hardware", None))):
        r.update(mode=mode, min_pressure_torr=p, procedure_name="tvac")
    with open_catalog(resolve_url(url)) as cat:
        cat.upsert(rows)
    capsys.readouterr()
    assert main(["runs", "--catalog", url, "--verdict", "passed"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert max(len(line) for line in lines) <= 80, "\n".join(lines)
    table = [line for line in lines if re.match(r"\d+ 20", line)]  # one line per run
    assert [("DRY-RUN" in line, " real " in line) for line in table] == [(m == "sim", m == "hardware") for m in
                                                                     [r["mode"] for r in sorted(rows, key=lambda r: r["started_utc"])]], "\n".join(lines)
    text = "\n".join(lines)
    assert "7.6e+02" not in text and " 760 " in text + " " and "1e-05" in text
    assert lines[-4:-1] == ["4 run(s):", "  real      2: 2 passed", "  DRY-RUN   2: 2 passed"]
    assert main(["runs", "--catalog", url, "--mode", "real"]) == 0
    assert "DRY-RUN" not in capsys.readouterr().out
    assert main(["runs", "--catalog", url, "--mode", "simulation"]) == 2
    assert capsys.readouterr().err.startswith("--mode: expected one of real, dry-run")


def test_unreachable_catalogue_only_warns(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with socket.socket() as s:  # a port nobody listens on: connection refused at once
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = write_procedure(tmp_path / "short.yaml", "  - power: {instrument: acs_board, on: true}\n"
                           "  - record: {instrument: acs_board, duration: 2 s}\n")
    code = main(["run", str(proc), "--config", str(SIM_CONFIG), "--sim", "--runs-dir", str(tmp_path / "runs"),
                 "--catalog", f"postgresql://bench:secret@127.0.0.1:{port}/bench"])
    out = capsys.readouterr()
    assert code == 0 and "COMPLETED" in out.out
    warnings = [line for line in out.err.splitlines() if "not catalogued" in line]
    assert len(warnings) == 2 and "at its start" in warnings[0] and "at its end" in warnings[1]
    assert "secret" not in out.err and "bench catalog rebuild" in warnings[1]
    (path,) = (tmp_path / "runs").glob("*.h5")
    assert read_run_summary(path).status == "completed"


def test_lab_config_names_the_catalogue(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "lab.yaml"
    text = SIM_CONFIG.read_text().replace("sensors/", str(ROOT / "configs" / "sensors") + "/")
    config.write_text(text.replace("instruments:", "catalog: shared/lab-catalog.sqlite\ninstruments:", 1))
    (tmp_path / "shared").mkdir()
    proc = write_procedure(tmp_path / "short.yaml", "  - power: {instrument: acs_board, on: true}\n")
    assert main(["run", str(proc), "--config", str(config), "--sim", "--runs-dir", str(tmp_path / "runs")]) == 0
    assert [r["procedure_name"] for r in rows_of(str(tmp_path / "shared" / "lab-catalog.sqlite"))] == ["short"]
    assert not (tmp_path / "runs" / CATALOG_FILE).exists()
    config.write_text(text.replace("instruments:", "catalog: mysql://u@h/db\ninstruments:", 1))
    capsys.readouterr()
    assert main(["run", str(proc), "--config", str(config), "--sim", "--runs-dir", str(tmp_path / "runs")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"{config}:") and ": catalog: unsupported catalogue backend 'mysql'" in err


def test_newer_schema_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    url = resolve_url(str(tmp_path / "c.sqlite"))
    with open_catalog(url) as cat, cat.transaction(write=True) as conn:
        conn.execute(catalog_schema.insert().values(version=99, applied_utc=NOW, software_version="9.9"))
    with pytest.raises(CatalogError, match="schema version 99 is newer"):
        open_catalog(url)
    assert main(["runs", "--catalog", str(tmp_path / "c.sqlite")]) == 1
    assert capsys.readouterr().err.startswith("bench: catalogue schema version 99 is newer")


def test_wal_mode_and_concurrent_writers(tmp_path: Path) -> None:
    """The embedded catalogue is in WAL mode, and two processes upserting at once both get through
    (the second waits for the write lock instead of failing)."""
    url = str(tmp_path / "c.sqlite")
    with open_catalog(resolve_url(url)) as cat, cat.transaction() as conn:
        assert conn.exec_driver_sql("PRAGMA journal_mode").scalar() == "wal"
    code = (
        "import sys; from bench.catalog.store import open_catalog, resolve_url; from tests.test_catalog import synthetic_rows\n"
        "rows = [dict(r, path=f'{r[\"path\"]}.{sys.argv[1]}') for r in synthetic_rows()]\n"
        "with open_catalog(resolve_url(sys.argv[2])) as cat:\n"
        "    for r in rows: cat.upsert([r])\n"
    )
    procs = [subprocess.Popen([sys.executable, "-c", code, str(i), url], cwd=ROOT, stderr=subprocess.PIPE, text=True) for i in range(2)]
    errs = [p.communicate(timeout=120)[1] for p in procs]
    assert [p.returncode for p in procs] == [0, 0], errs
    assert len(rows_of(url)) == 2 * len(synthetic_rows())


def test_rebuild_moves_nothing_but_rows(tmp_path: Path) -> None:
    """Rebuild never writes next to the run files except the catalogue itself, and never alters them."""
    src = ROOT / "tests" / "sessions"
    files = sorted(src.glob("*.h5"))[:3]
    if not files:
        pytest.skip("no committed sessions in tests/sessions")
    runs = tmp_path / "runs"
    runs.mkdir()
    for f in files:
        shutil.copy2(f, runs / f.name)
    before = {p.name: sha256(p) for p in runs.iterdir()}
    assert main(["catalog", "rebuild", str(runs)]) == 0
    assert {p.name: sha256(p) for p in runs.glob("*.h5")} == before
    assert {p.name for p in runs.iterdir()} - set(before) <= {CATALOG_FILE, f"{CATALOG_FILE}-wal", f"{CATALOG_FILE}-shm"}
    assert {r["file_sha256"] for r in rows_of(str(runs / CATALOG_FILE))} == set(before.values())
