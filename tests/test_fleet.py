"""``bench fleet``: many run files on dask.distributed worker processes give what the serial
commands give each file alone; a bad file is reported and the rest finish; bad input is exit 2.

One ``LocalCluster`` (processes, 127.0.0.1) is shared by the module and reached with
``--scheduler``; one test starts the embedded cluster itself.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import h5py
import numpy as np
import pytest

from bench.cli import main
from bench.errors import EXIT_BAD_INPUT, EXIT_FAILED, EXIT_OK
from bench.fleet.files import destination
from tests.cli_output import one_error_line

SESSIONS = Path(__file__).resolve().parent / "sessions"
RATE = SESSIONS / "rate_transfer_short.h5"
CHAMBER = SESSIONS / "chamber_short.h5"


@pytest.fixture(scope="module")
def scheduler():
    """The address of a LocalCluster of 2 worker processes on 127.0.0.1, for the module."""
    from distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None,
                      silence_logs=40) as cluster:
        yield cluster.scheduler_address


def _run(capsys, *argv: str) -> tuple[int, str, str]:
    capsys.readouterr()
    rc = main(list(argv))
    out, err = capsys.readouterr()
    return rc, out, err


def _fleet_json(capsys, *argv: str) -> tuple[int, dict]:
    rc, out, err = _run(capsys, "fleet", *argv, "--json")
    assert out.strip(), err
    return rc, json.loads(out)


def _serial_replay(capsys, path: Path, runs_dir: Path) -> tuple[int, str, str]:
    """Exit code, verdict (MATCH / DIVERGED / ERROR) and stderr of ``bench replay FILE`` alone."""
    rc, out, err = _run(capsys, "replay", str(path), "--runs-dir", str(runs_dir))
    verdict = "MATCH" if "\nMATCH" in out else "DIVERGED" if "\nDIVERGED" in out else "ERROR"
    return rc, verdict, err.strip()


def _diverging_copy(dst: Path) -> Path:
    """rate_transfer_short.h5 whose stored procedure levels the table at 1 deg at the end instead of
    0 deg: its replay sends another target position than the recording, so it diverges."""
    shutil.copy(RATE, dst)
    old = b"angle: 0 deg, name: level table}"
    with h5py.File(dst, "r+") as f:
        text = bytes(f["procedure/text"][()])
        assert text.count(old) == 1
        f["procedure/text"][()] = np.bytes_(text.replace(old, b"angle: 1 deg, name: level table}"))
    return dst


def test_fleet_replay_of_the_sessions_gives_each_file_its_serial_verdict(scheduler, tmp_path, capsys):
    rc, doc = _fleet_json(capsys, "replay", str(SESSIONS), "--scheduler", scheduler, "--out", str(tmp_path / "fleet"))
    files = sorted(SESSIONS.glob("*.h5"))
    assert [Path(r["path"]).name for r in doc["files"]] == [f.name for f in files]
    serial = {f.name: _serial_replay(capsys, f, tmp_path / "serial") for f in files}
    for r in doc["files"]:
        code, verdict, _err = serial[Path(r["path"]).name]
        assert (r["exit_code"], r["verdict"]) == (code, verdict), r
        assert Path(r["output"]).parent == tmp_path / "fleet" and Path(r["output"]).is_file()
    assert rc == (EXIT_OK if all(c == EXIT_OK for c, _v, _e in serial.values()) else EXIT_FAILED)
    assert doc["totals"]["files"] == len(files) and doc["scheduler"] == scheduler


def test_a_bad_file_among_good_ones_is_reported_and_the_rest_finish_on_the_embedded_cluster(tmp_path, capsys):
    src = tmp_path / "runs"
    (src / "sub").mkdir(parents=True)
    shutil.copy(RATE, src / "good.h5")
    _diverging_copy(src / "sub" / "diverged.h5")
    (src / "notes.h5").write_text("not a run file\n")
    (src / "sub" / "truncated.h5").write_bytes(RATE.read_bytes()[:200_000])
    rc, out, err = _run(capsys, "fleet", "replay", str(src), "--workers", "1", "--out", str(tmp_path / "out"), "--json")
    doc = json.loads(out)
    assert rc == EXIT_FAILED
    assert doc["scheduler"].startswith("tcp://127.0.0.1:")  # the embedded cluster listens on loopback only
    got = {r["rel"]: r for r in doc["files"]}
    assert sorted(got) == ["good.h5", "notes.h5", "sub/diverged.h5", "sub/truncated.h5"]
    for rel, r in got.items():
        code, verdict, serial_err = _serial_replay(capsys, src / rel, tmp_path / "serial")
        assert (r["exit_code"], r["verdict"]) == (code, verdict), rel
        if code == EXIT_BAD_INPUT:
            assert r["error"] == serial_err  # the serial command's one line
            assert rel in err  # reported on stderr as it happened
    assert "fleet replay: 4/4 files, 3 failed" in err  # progress: files done / total, failures so far
    assert (got["good.h5"]["verdict"], got["sub/diverged.h5"]["verdict"]) == ("MATCH", "DIVERGED")
    assert got["notes.h5"]["exit_code"] == got["sub/truncated.h5"]["exit_code"] == EXIT_BAD_INPUT
    assert Path(got["sub/diverged.h5"]["output"]).parent == tmp_path / "out" / "sub"  # inside OUT, beside its source's name


@pytest.mark.parametrize("command", [["diagnose"], ["calibrate", "noise"]], ids=["diagnose", "calibrate-noise"])
def test_fleet_json_of_each_file_is_the_serial_commands_json(command, scheduler, tmp_path, capsys):
    out = tmp_path / "out"
    rc, doc = _fleet_json(capsys, *command[:1], *command[1:], str(SESSIONS), "--scheduler", scheduler, "--out", str(out))
    suffix = ".diagnose.json" if command[0] == "diagnose" else ".noise.json"
    results = {Path(r["path"]).name: r for r in doc["files"]}
    assert len(results) == 3
    for name, r in results.items():
        code, serial_out, serial_err = _run(capsys, *command, str(SESSIONS / name), "--json")
        assert r["exit_code"] == code, name
        if code == EXIT_OK:
            assert r["payload"] == json.loads(serial_out)
            assert (out / (Path(name).stem + suffix)).read_text() == serial_out  # byte for byte what the command prints
        else:
            serial = subprocess.CompletedProcess(command, code, serial_out, serial_err)
            assert r["error"] == one_error_line(serial, code) and not (out / (Path(name).stem + suffix)).exists()
    assert results["rate_transfer_short.h5"]["exit_code"] == EXIT_OK  # one file has sensor data, the chamber runs none
    assert rc == EXIT_FAILED


def test_a_catalogue_query_selects_the_files(scheduler, tmp_path, capsys):
    runs = tmp_path / "runs"
    runs.mkdir()
    for f in (RATE, CHAMBER):
        shutil.copy(f, runs / f.name)
    assert main(["catalog", "rebuild", str(runs)]) == EXIT_OK
    rc, out, _err = _run(capsys, "fleet", "replay", "--query", "--runs-dir", str(runs), "--procedure", "chamber_*",
                         "--scheduler", scheduler, "--out", str(tmp_path / "out"))
    assert rc == EXIT_OK
    # the summary table: one row per file of the query, then the totals
    assert "chamber_short.h5" in out and "MATCH" in out and "rate_transfer" not in out
    assert "1 file(s): 1 ok, 0 failed" in out


@pytest.mark.parametrize("argv, field", [
    (["replay", "/nonexistent/dir"], "DIR: /nonexistent/dir: no such directory"),
    (["replay", "{empty}"], "no *.h5 run file"),
    (["replay", str(SESSIONS), "--scheduler", "localhost:8786"], "--scheduler: expected a scheduler address"),
    (["replay", str(SESSIONS), "--scheduler", "tcp://127.0.0.1:1", "--timeout", "1 s"], "--scheduler: no dask scheduler answered"),
    (["replay", str(SESSIONS), "--unit", "SN1"], "--unit: --unit filters catalogue rows: add --query"),
    (["replay", "--query", "--runs-dir", "{empty}", "--unit", "SN1"], "--runs-dir: no catalogue"),
    (["replay", str(SESSIONS), "--workers", "0"], "--workers: expected at least 1 worker"),
    (["calibrate", "noise", str(SESSIONS), "--degree", "2"], "--degree applies to the thermal method only"),
    (["report", str(SESSIONS), "--out", "{taken}"], "exists (and 2 more); choose another --out"),
], ids=["no-dir", "no-files", "bad-url", "no-scheduler", "filter-without-query", "no-catalogue", "no-workers",
        "bad-option", "outputs-exist"])
def test_bad_input_is_one_located_line_and_exit_2(argv, field, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the default --out (runs/fleet) is made here, if at all
    (tmp_path / "empty").mkdir()
    (tmp_path / "taken").mkdir()
    for f in SESSIONS.glob("*.h5"):
        (tmp_path / "taken" / f"{f.stem}.html").write_text("an earlier report")
    argv = [a.format(empty=tmp_path / "empty", taken=tmp_path / "taken") for a in argv]
    rc, out, err = _run(capsys, "fleet", *argv)
    assert rc == EXIT_BAD_INPUT
    assert field in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert all((tmp_path / "taken" / f"{f.stem}.html").read_text() == "an earlier report" for f in SESSIONS.glob("*.h5"))


@pytest.mark.parametrize("rel", ["../escape.h5", "/abs/run.h5", "a/../../b.h5"])
def test_no_output_is_named_outside_the_output_directory(rel, tmp_path):
    with pytest.raises(ValueError):
        destination(tmp_path, rel, "report")
    assert destination(tmp_path, "sub/run.h5", "report") == tmp_path / "sub" / "run.html"
    assert destination(tmp_path, "run.h5", "calibrate", "noise") == tmp_path / "run.noise.json"


def test_the_embedded_cluster_listens_on_loopback_only_and_uses_processes():
    import os

    import psutil

    from bench.fleet.cluster import connect

    with connect(None, workers=1, timeout_s=60) as ws:
        me = psutil.Process(os.getpid())
        children = me.children(recursive=True)
        listening = [c.laddr for p in [me, *children] for c in p.net_connections(kind="inet") if c.status == psutil.CONN_LISTEN]
        info = ws.client.scheduler_info(n_workers=-1)["workers"]
    assert ws.embedded and ws.address.startswith("tcp://127.0.0.1:")
    assert listening and {a.ip for a in listening} == {"127.0.0.1"}, listening
    assert all(w["nthreads"] == 1 for w in info.values()) and len(info) == 1
    assert children  # the worker runs in a process of its own, not a thread of this one
