"""Reliability III (issue 31) at the web station, over real HTTP against ``bench serve``: each case
of the adversarial pass that failed before (S1-S7, S10, T1-T3; docs/reliability.md).

One station serves most tests (module fixture), with a short ``--request-timeout`` so that the
slow-request cases take seconds. Requests are made with ``http.client`` so that the ``Host``,
``Content-Length`` and proxy headers are exactly what the test says.
"""

from __future__ import annotations

import concurrent.futures
import http.client
import json
import os
import socket
import sqlite3
import subprocess
import time
from pathlib import Path
from urllib.parse import urlsplit

import h5py
import numpy as np
import pytest

from bench.record import read_run_summary
from tests.browser import ROOT, TOKEN, Server, make_run_file
from tests.test_web_station import _wait

PROCEDURES = ROOT / "tests" / "data" / "procedures"
SIM_CONFIG = ROOT / "configs" / "sim.yaml"
REQUEST_TIMEOUT_S = 2.0


class Client:
    """HTTP requests to one station, headers as given."""

    def __init__(self, url: str):
        u = urlsplit(url)
        self.host, self.port = u.hostname, u.port

    def request(self, method: str, path: str, body: bytes | dict | None = None, *, token: str | None = None,
                headers: dict[str, str] | None = None, timeout: float = 30) -> tuple[int, dict]:
        c = http.client.HTTPConnection(self.host, self.port, timeout=timeout)
        h = {"Host": f"{self.host}:{self.port}", **(headers or {})}
        if token is not None:
            h["Authorization"] = f"Bearer {token}"
        data = json.dumps(body).encode() if isinstance(body, dict) else body
        if data is not None:
            h.setdefault("Content-Type", "application/json")
        try:
            c.putrequest(method, path, skip_host=True, skip_accept_encoding=True)
            for k, v in h.items():
                c.putheader(k, v)
            if data is not None and "Content-Length" not in h and "Transfer-Encoding" not in h:
                c.putheader("Content-Length", str(len(data)))
            c.endheaders(data, encode_chunked="Transfer-Encoding" in h)
            r = c.getresponse()
            raw = r.read()
            ctype = r.getheader("content-type", "")
            return r.status, (json.loads(raw) if raw and "json" in ctype else {"raw": raw})
        finally:
            c.close()

    def get(self, path: str, **kw) -> tuple[int, dict]:
        return self.request("GET", path, **kw)

    def post(self, path: str, body: dict | bytes, **kw) -> tuple[int, dict]:
        return self.request("POST", path, body, token=kw.pop("token", TOKEN), **kw)


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    base = tmp_path_factory.mktemp("guards")
    runs = base / "runs"
    runs.mkdir()
    first = make_run_file(runs, procedure="first_run", unit="SN-A")
    (runs / "innocent.h5").symlink_to(make_run_file(base / "elsewhere", procedure="secret_project"))  # a link out (S7)
    bad = make_run_file(base / "bad", procedure="bad_name")
    Path(os.fsdecode(bytes(runs) + b"/bad\xff.h5")).write_bytes(bad.read_bytes())  # a name that is not UTF-8 (T1)
    server = Server(runs, "--procedures", str(PROCEDURES), "--config", str(SIM_CONFIG), "--request-timeout", f"{REQUEST_TIMEOUT_S} s")
    server.client = Client(server.url)
    server.first = first.name
    yield server
    err = server.stop()
    assert "Traceback" not in err, err


def _started(station, **extra) -> str:
    """A dry-run of web_prompt.yaml on the wall clock, waiting at its prompt; its run id."""
    status, body = station.client.post("/api/start", {"procedure": "web_prompt.yaml", "params": {"hold": "10 min"}, **extra})
    assert status == 200, body
    rid = body["id"]
    _wait(lambda: (station.client.get(f"/api/live?id={rid}")[1].get("control") or {}).get("prompt"), 60, "the prompt")
    return rid


def _stopped(station, rid: str) -> None:
    station.client.post("/api/stop", {"id": rid})
    _wait(lambda: not (station.client.get(f"/api/live?id={rid}")[1].get("control") or {}).get("running"), 60, "the run to end")


# ---- S3: only the station's own names -------------------------------------------------------------
def test_a_foreign_host_name_gets_nothing(station) -> None:
    rid = station.first
    for path in ("/api/runs", f"/api/file?id={rid}", f"/api/run?id={rid}", "/"):
        status, body = station.client.get(path, headers={"Host": f"attacker.example:{station.client.port}"})
        assert status == 421 and "attacker.example" in body["errors"][0] and "runs" not in body, (path, body)
    for host in ("localhost", f"localhost:{station.client.port}", f"127.0.0.1:{station.client.port}", "LOCALHOST."):
        assert station.client.get(f"/api/run?id={rid}", headers={"Host": host})[0] == 200, host


# ---- S4, S5 (operator), T3: strictly typed fields ----------------------------------------------------------
@pytest.mark.parametrize("extra, field", [
    ({"accept_overdue": "no"}, "accept_overdue"), ({"accept_overdue": "false"}, "accept_overdue"),
    ({"dry_run": "false"}, "dry_run"), ({"dry_run": 0}, "dry_run"), ({"realtime": "true"}, "realtime"),
    ({"dry_run": True, "acept_overdue": True}, "unknown field"), ({"operator": "x" * 65}, "operator"),
    ({"operator": "Mallory\x1b[2J"}, "operator"), ({"unit": "SN\x00"}, "unit"), ({"params": {"hold": "1 s\n- call: x"}}, "params.hold"),
    ({"params": {"hold": float("nan")}}, "NaN is not JSON"),
])
def test_start_fields_are_typed_strictly(station, extra, field) -> None:
    before = set(station.runs_dir.glob("*.h5"))
    body = json.dumps({"procedure": "web_prompt.yaml", **extra}).encode()  # NaN as JSON's NaN, which is not JSON
    status, reply = station.client.post("/api/start", body)
    assert status == 400 and field in reply["errors"][0], reply
    assert set(station.runs_dir.glob("*.h5")) == before  # nothing started (a start makes its file before it answers)


def test_control_fields_and_queries_are_typed_strictly(station) -> None:
    c = station.client
    for path, body, field in (("/api/pause", {"id": "x.h5", "paused": "true"}, "paused"), ("/api/stop", {"id": 5}, "id"),
                              ("/api/answer", {"id": "x.h5", "answer": ["yes"]}, "answer")):
        status, reply = c.post(path, body)
        assert status == 400 and field in reply["errors"][0], (path, reply)
    for path, field in (("/api/plan?procedure=web_prompt.yaml&params=notjson", "params"), ("/api/runs?unit=SN%00", "unit"),
                        ("/api/stream?id=a.h5&px=1e9", "px"), ("/api/xy?id=a.h5&t0=nan", "t0"),
                        ("/api/runs?procedure=" + "x" * 300, "procedure")):
        status, reply = c.get(path)
        assert status == 400 and reply["errors"][0].startswith(field), (path, reply)


# ---- S5, S2: the recorded origin, and a stop that reads cannot hold up --------------------------------------
def test_stop_is_answered_while_reads_wait_on_a_locked_catalogue_and_records_the_true_origin(station) -> None:
    c = station.client
    rid = _started(station, operator="Ada Lovelace")
    forged = {"X-Forwarded-For": "203.0.113.66", "Forwarded": "for=203.0.113.66"}
    assert c.post("/api/pause", {"id": rid, "paused": True}, headers=forged)[0] == 200
    controls = _wait(lambda: [json.loads(e.message) for e in read_run_summary(station.runs_dir / rid).events if e.kind == "control"],
                     30, "the pause in the file")
    assert [x["origin"] for x in controls] == ["web 127.0.0.1"], controls  # before: web 203.0.113.66
    make_run_file(station.runs_dir, procedure="not_catalogued_yet")  # each /api/runs would have written it
    lock = sqlite3.connect(station.runs_dir / "catalog.sqlite", isolation_level=None, timeout=0)
    lock.execute("BEGIN EXCLUSIVE")  # another process holds the catalogue's write lock
    try:
        with concurrent.futures.ThreadPoolExecutor(48) as pool:
            reads = [pool.submit(c.get, "/api/runs") for _ in range(45)]
            time.sleep(0.5)
            t0 = time.monotonic()
            status, body = c.post("/api/stop", {"id": rid, "operator": "Ada Lovelace"}, headers=forged)
            stop_s = time.monotonic() - t0
            results = [f.result(timeout=60) for f in reads]
    finally:
        lock.execute("ROLLBACK")
        lock.close()
    assert status == 200, body
    assert stop_s < 3.0, f"the stop took {stop_s:.1f} s"  # before: unanswered for 30 s
    assert all(s == 200 and any(r["procedure_name"] == "not_catalogued_yet" for r in b["runs"]) for s, b in results)
    _wait(lambda: not c.get(f"/api/live?id={rid}")[1]["control"]["running"], 60, "the run to stop")
    s = read_run_summary(station.runs_dir / rid)
    stops = [json.loads(e.message) for e in s.events if e.kind == "control"]
    assert [(x["action"], x["origin"]) for x in stops] == [("pause", "web 127.0.0.1"), ("stop", "web 127.0.0.1")], stops
    assert "203.0.113.66" not in json.dumps([e.message for e in s.events]) and "203.0.113.66" not in s.abort_reason
    assert s.attrs["operator"] == "Ada Lovelace"


# ---- S6: no process per plan ---------------------------------------------------------------------------------
def _children(pid: int) -> int:
    out = subprocess.run(["ps", "-o", "pid=", "--ppid", str(pid)], capture_output=True, text=True).stdout
    return len(out.split())


def test_plans_start_no_process(station) -> None:
    c = station.client
    assert c.get("/api/plan?procedure=web_prompt.yaml")[0] == 200  # warm: the first one loads the unit registry
    most = 0
    with concurrent.futures.ThreadPoolExecutor(12) as pool:
        t0 = time.monotonic()
        futures = [pool.submit(c.get, f"/api/plan?procedure=web_prompt.yaml&params=%7B%22hold%22%3A%22{i + 1}%20min%22%7D")
                   for i in range(12)]
        while not all(f.done() for f in futures):
            most = max(most, _children(station.proc.pid))
            time.sleep(0.02)
        wall = time.monotonic() - t0
    results = [f.result() for f in futures]
    assert all(s == 200 and b["ok"] and "long recording" in b["text"] for s, b in results), results[0]
    assert most == 0, f"{most} child processes"  # before: one Python process per plan
    assert wall < 15, wall


# ---- S10: requests that never end, bodies larger than allowed -------------------------------------------------
def test_incomplete_requests_are_closed_and_big_bodies_refused_before_reading(station) -> None:
    c = station.client
    socks = []
    for i in range(20):
        s = socket.create_connection((c.host, c.port), timeout=10)
        s.sendall(b"GET /api/runs HTTP/1.1\r\nHost: localhost\r\nX-Slow: " if i % 2 else
                  b"POST /api/stop HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\nContent-Length: 1000\r\n"
                  b"Authorization: Bearer " + TOKEN.encode() + b"\r\n\r\n{\"id\":")
        socks.append(s)
    time.sleep(REQUEST_TIMEOUT_S + 1.5)
    closed = 0
    for s in socks:
        s.settimeout(5)
        data = s.recv(65536)
        while data and not data.endswith(b"]}"):
            more = s.recv(65536)
            if not more:
                break
            data += more
        closed += (data.startswith(b"HTTP/1.1 408") and s.recv(1) == b"") or data == b""
        s.close()
    assert closed == 20  # before: 20 of 20 still open after 65 s
    # 200 MB announced: refused at once, before a byte of it is read
    s = socket.create_connection((c.host, c.port), timeout=10)
    t0 = time.monotonic()
    s.sendall(b"POST /api/start HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\nContent-Length: 200000000\r\n"
              b"Authorization: Bearer " + TOKEN.encode() + b"\r\n\r\n" + b" " * 1000)
    reply = s.recv(4096)
    s.close()
    assert reply.startswith(b"HTTP/1.1 413") and time.monotonic() - t0 < 2, reply[:100]
    # without a length (chunked), refused once 64 KiB have arrived
    status, body = c.post("/api/start", iter([b"{\"procedure\": \"" + b"x" * 70_000 + b"\"}"]),
                          headers={"Transfer-Encoding": "chunked"})
    assert status == 413, body


# ---- S1: a file that still holds a credential is not served ---------------------------------------------------------
def test_a_run_file_holding_a_credential_is_not_served(station) -> None:
    old = make_run_file(station.runs_dir, procedure="old_with_secret")
    with h5py.File(old, "r+") as f:  # as an older bench stored its config: verbatim
        del f["config/text"]
        raw = b"name: lab\ncatalog: postgresql://bench:Tr0ub4dor-3@labdb/bench\n"
        f["config"].create_dataset("text", data=np.array(raw, dtype=f"S{len(raw)}"))
        f.attrs["abort_reason"] = "catalogue postgresql://bench:Tr0ub4dor-3@labdb/bench unreachable"
    c = station.client
    status, body = c.get(f"/api/file?id={old.name}")
    assert status == 403 and "credential" in body["errors"][0] and "Tr0ub4dor" not in json.dumps(body), body
    status, body = c.get(f"/api/run?id={old.name}")
    assert status == 200 and "Tr0ub4dor" not in json.dumps(body) and "bench:***@labdb" in json.dumps(body)
    new = make_run_file(station.runs_dir, procedure="new_clean")
    status, body = c.get(f"/api/file?id={new.name}")
    assert status == 200 and body["raw"][:8] == b"\x89HDF\r\n\x1a\n"


# ---- S7, T1, T2: the runs table (last: it breaks the module station's catalogue) ---------------------------------
def test_runs_table_skips_links_out_and_bad_names_and_survives_a_broken_catalogue(station) -> None:
    c = station.client
    status, body = c.get("/api/runs")
    assert status == 200, body
    names = {r["procedure_name"] for r in body["runs"]}
    assert "first_run" in names and "secret_project" not in names and "bad_name" not in names, names  # no link out, no undecodable name
    assert c.get("/api/file?id=innocent.h5")[0] == 400
    # a garbage catalogue: a warning and the runs read from the files, never a server error
    runs = station.runs_dir
    (runs / "catalog.sqlite").write_bytes(b"garbage, not a database\n" * 50)
    for p in runs.glob("catalog.sqlite-*"):
        p.unlink(missing_ok=True)  # (the cataloguer may close its connection meanwhile)
    status, body = c.get("/api/runs")
    assert status == 200 and "first_run" in {r["procedure_name"] for r in body["runs"]}, body
    assert "not a SQLite database" in body["warnings"][0] and "move it aside" in body["warnings"][0]
