"""Operator's station II (issue 30) under Reliability III (issue 31): what the two issues built side
by side, checked where they meet.

* the unit page and the acceptance package read through the runs index (a request never writes
  the catalogue: answered while another process holds its write lock), skip a link out of the runs
  directory, mask a credential, and are behind the Host allow-list and the typed request parser;
* every field issue 30 added (``confirm_abort``, ``mode``, ``serial``, the acting ``operator``) is
  typed strictly, and the operator's name follows one rule, the same for ``bench run --operator``,
  the lab's ``operators:`` and the web;
* answers, check names and runs decoded from a run file never act on the terminal in issue 30's
  views (``bench inspect``'s tables and sentences, ``bench unit``);
* a run whose instrument cannot be opened leaves nothing behind: neither its placeholder name nor
  the hidden file it was being set up in.
"""

from __future__ import annotations

import json
import os
import shutil
import sqlite3
import time
from pathlib import Path

import h5py
import pytest

from tests.browser import Server
from tests.conftest import ROOT, SIM_CONFIG
from tests.test_hostile_files import ESCAPES, _cli
from tests.test_web_guards import Client
from tests.test_web_station import _wait

PROCEDURES = ROOT / "tests" / "data" / "procedures"
SECRET = "Tr0ub4dor-3"


@pytest.fixture(scope="module")
def station(unit_runs, tmp_path_factory):
    base = tmp_path_factory.mktemp("unit_guards")
    runs = base / "runs"
    shutil.copytree(unit_runs, runs, ignore=shutil.ignore_patterns("catalog.sqlite*"))
    sn12 = sorted(p for p in runs.glob("*.h5") if h5py.File(p, "r").attrs.get("unit_serial") == "SN12")
    (base / "elsewhere").mkdir()
    outside = shutil.copy(sn12[-1], base / "elsewhere" / "outside_of_the_runs_dir.h5")
    (runs / "zz_link_out.h5").symlink_to(outside)  # a run of SN12 reached through a link out (S7): never read
    server = Server(runs, "--procedures", str(PROCEDURES), "--config", str(SIM_CONFIG))
    server.client = Client(server.url)
    server.sn12 = sn12
    yield server
    err = server.stop()
    assert "Traceback" not in err, err


def _catalogued(runs: Path) -> int:
    db = runs / "catalog.sqlite"
    if not db.exists():
        return 0
    with sqlite3.connect(db, timeout=1) as c:
        try:
            return c.execute("select count(*) from runs").fetchone()[0]
        except sqlite3.Error:
            return 0


def test_the_unit_page_reads_through_the_index_skips_links_out_and_masks_credentials(station) -> None:
    c, runs = station.client, station.runs_dir
    assert c.get("/api/runs")[0] == 200  # the background cataloguer writes the catalogue
    _wait(lambda: _catalogued(runs) >= 10, 60, "the runs catalogued in the background")
    late = shutil.copy(station.sn12[0], runs / "zz_late_sn12.h5")  # a run of SN12 not catalogued yet
    with h5py.File(late, "r+") as f:  # as an older bench stored its operator: verbatim, with a credential
        f.attrs["operator"] = f"postgresql://bench:{SECRET}@labdb/bench"
    lock = sqlite3.connect(runs / "catalog.sqlite", isolation_level=None, timeout=0)
    lock.execute("BEGIN EXCLUSIVE")  # another process holds the catalogue's write lock
    try:
        t0 = time.monotonic()
        status, body = c.get("/api/unit?serial=SN12")
        took = time.monotonic() - t0
        pstatus, package = c.get("/api/unit_package?serial=SN12")
    finally:
        lock.execute("ROLLBACK")
        lock.close()
    assert status == 200, body
    assert took < 8.0, f"{took:.1f} s"  # before: the request catalogued the new file itself and waited for the lock
    paths = [r["path"] for r in body["runs"]]
    assert len(paths) == 4 and str(Path(late).resolve()) in paths, paths  # 3 catalogued + the new file, read from it
    text = json.dumps(body)
    assert "outside_of_the_runs_dir" not in text and "elsewhere" not in text  # the link out: neither listed nor read
    assert SECRET not in text and "bench:***@labdb" in text
    assert pstatus == 200 and SECRET not in package["raw"].decode() and b"SN12" in package["raw"]


def test_issue_30s_fields_are_typed_and_guarded(station) -> None:
    c = station.client
    assert c.get("/api/unit?serial=SN12", headers={"Host": f"attacker.example:{c.port}"})[0] == 421
    for path, field in (("/api/unit?serial=SN%00", "serial"), ("/api/unit?serial=" + "x" * 65, "serial"),
                        ("/api/unit_package?serial=SN12&part=" + "P" * 65, "part"), ("/api/runs?mode=bogus", "mode")):
        status, reply = c.get(path)
        assert status == 400 and reply["errors"][0].startswith(field), (path, reply)
    assert c.get("/api/unit?serial=SN99")[0] == 404
    for body, field in (({"id": "x.h5", "answer": "no", "confirm_abort": "true"}, "confirm_abort"),
                        ({"id": "x.h5", "answer": "no", "confirm_abort": 1}, "confirm_abort"),
                        ({"id": "x.h5", "answer": "yes", "operator": "ana\x1b[2J"}, "operator"),
                        ({"id": "x.h5", "paused": True, "operator": "a" * 65}, "operator")):
        status, reply = c.post("/api/pause" if "paused" in body else "/api/answer", body)
        assert status == 400 and reply["errors"][0].startswith(f"{field}: "), (body, reply)
        assert "expected" in reply["errors"][0] or "control character" in reply["errors"][0], reply  # the parser's words


def test_an_operator_name_follows_one_rule_everywhere() -> None:
    from bench.errors import InputError
    from bench.operators import check_name
    from bench.web.requests import operator_name

    for name in ("ana", "Dr. Müller (QA)", "O'Brien", "李雷", "night shift #2"):
        assert operator_name(f"  {name} ") == check_name(name, "--operator") == name  # the CLI's and the lab's names work on the web
    assert operator_name("   ") == ""  # blank: not given (the start then asks who runs it)
    for bad in ("a" * 65, "ana\x1b[2J", "ana\nbob", "ana\u202e"):
        with pytest.raises(InputError):
            operator_name(bad)
        with pytest.raises(InputError):
            check_name(bad, "--operator")


def test_texts_decoded_from_a_run_file_never_act_on_the_terminal_in_issue_30s_views(tmp_path, capsys) -> None:
    import numpy as np

    from bench.catalog.rebuild import rebuild
    from bench.catalog.store import open_catalog, resolve_url
    from bench.event_text import event_text
    from bench.record import Column, RunRecorder

    runs = tmp_path / "runs"
    rec = RunRecorder.create(runs, procedure_name=f"p{ESCAPES}", procedure_text="name: p\n", procedure_path="p.yaml", config_text="name: t\n",
                             config_path="lab.yaml", mode="sim", software_version="test", identity={"unit_serial": "SN1"})
    key = rec.add_stream("board", [Column("temp", "degC", "f8")], rate_hz=10.0)
    rec.start()
    # JSON escapes (\u001b) are no control characters in the stored text, but are once decoded
    answer = json.dumps({"answer": f"yes{ESCAPES}", "source": "web 127.0.0.1", "operator": f"ana{ESCAPES}", "id": f"mount{ESCAPES}"})
    control = json.dumps({"action": "stop", "origin": "web 127.0.0.1", "operator": f"bob{ESCAPES}", "message": f"halt{ESCAPES}"})
    assert "\x1b" not in answer + control
    rec.event("step_start", "check", f"bias{ESCAPES}", t_s=0.0, step=0)
    rec.event("operator", "prompt", answer, t_s=0.1, step=0)
    rec.event("control", "web", control, t_s=0.2, step=0)
    rec.event("check", "bias", "passed", t_s=0.3, step=0,
              data=json.dumps({"signal": f"board.temp{ESCAPES}", "statistic": "mean", "value": 20.0, "min": 0, "max": 40}).encode())
    rec.event("step_end", "check", "passed", t_s=0.3, step=0)
    rec.append(key, np.arange(5) / 10.0, temp=np.full(5, 20.0))
    rec.tick(0.5)
    rec.close("completed")
    for kind, message in (("operator", answer), ("control", control)):
        shown = event_text(kind, "web", message)
        assert "\x1b" not in shown and "\u202e" not in shown and "\\x1b[2J" in shown, shown
    with open_catalog(resolve_url(None, runs)) as cat:
        rebuild(cat, runs)
    for args in (("inspect", str(rec.path)), ("unit", "SN1", "--runs-dir", str(runs))):
        code, out, err = _cli(capsys, *args)
        assert code == 0, err
        for ch in "\x1b\x07\x9b\u202e":
            assert ch not in out, (args, repr(ch))
        assert "\\x1b[2J" in out, args
    code, out, _ = _cli(capsys, "inspect", str(rec.path))
    flat = out.replace("\n", "").replace(" ", "")
    assert "board.temp\\x1b[2J" in flat and "ana\\x1b[2J" in flat and "bob\\x1b[2J" in flat  # the check and the sentences, escaped


@pytest.mark.parametrize("closing_fails", [False, True])
def test_a_run_whose_instrument_cannot_be_opened_leaves_nothing(tmp_path, monkeypatch, closing_fails) -> None:
    from bench.errors import RecorderError
    from bench.lab import InstrumentOpenError
    from bench.runner import session
    from bench.runner.operator import Operator
    from bench.validate import load_checked

    def no_instrument(*_a, **_k):
        raise InstrumentOpenError("acs_board", "no answer to the identification query", "check the cable", OSError("timeout"))

    monkeypatch.setattr(session, "open_lab", no_instrument)
    if closing_fails:  # the file cannot be finalised and moved to its name: the hidden file is removed all the same
        import bench.record.writer as writer

        def fail(*_a, **_k):
            raise OSError("disk gone")

        monkeypatch.setattr(writer, "finalise_status", fail)
    procedure, config = load_checked(PROCEDURES / "web_prompt.yaml", SIM_CONFIG, {})
    runs = tmp_path / "runs"
    with pytest.raises((InstrumentOpenError, RecorderError)):
        session.start_run(procedure, config, procedure_path=PROCEDURES / "web_prompt.yaml", config_path=SIM_CONFIG, runs_dir=runs,
                          sim=True, realtime=False, operator=Operator(), progress=None)
    assert os.listdir(runs) == []  # no placeholder, no .NAME.h5.partial, no .new, no reserve, no catalogue
