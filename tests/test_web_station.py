"""The web station (`bench serve`) end to end in a real browser (Debian's chromium driven by
Playwright), plus its HTTP access rules, decimation and path checks without a browser.

The browser tests are skipped, with the reason, where chromium or playwright is missing
(tests/browser.py).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from bench.record import read_run_summary
from tests.browser import ROOT, TOKEN, Server, chromium_path, launch_browser, make_run_file, until

PROCEDURES = ROOT / "tests" / "data" / "procedures"
SIM_CONFIG = ROOT / "configs" / "sim.yaml"


def _request(url: str, body: dict | None = None, token: str | None = None) -> tuple[int, dict]:
    headers = {"Content-Type": "application/json"}
    if token is not None:
        headers["Authorization"] = f"Bearer {token}"
    req = urllib.request.Request(url, data=None if body is None else json.dumps(body).encode(), headers=headers,
                                 method="GET" if body is None else "POST")
    try:
        with urllib.request.urlopen(req, timeout=30) as r:
            return r.status, json.loads(r.read() or b"{}")
    except urllib.error.HTTPError as e:
        return e.code, json.loads(e.read() or b"{}")


def _wait(cond, timeout_s: float, what: str, period_s: float = 0.2):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        v = cond()
        if v:
            return v
        time.sleep(period_s)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")


@pytest.fixture(scope="module")
def browser():
    yield from launch_browser()


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    runs = tmp_path_factory.mktemp("web") / "runs"
    server = Server(runs, "--procedures", str(PROCEDURES), "--config", str(SIM_CONFIG))
    yield server
    err = server.stop()
    assert "Traceback" not in err, err


def _page(browser, url: str):
    page = browser.new_page(viewport={"width": 1280, "height": 900})
    page.set_default_timeout(20_000)
    page.goto(url)
    return page


def _num(page, selector: str, attr: str) -> int:
    v = page.get_attribute(selector, attr)
    return int(v) if v else 0


def _set_token(page) -> None:
    page.fill("#token-input", TOKEN)
    page.click("#token-save")
    page.wait_for_selector("#token-state.ok")


# ---- end to end ---------------------------------------------------------------------------------
def test_dry_run_from_the_page_is_watched_answered_and_stopped(browser, station):
    page = _page(browser, station.url + "start")
    _set_token(page)
    page.select_option("#s-procedure", "web_prompt.yaml")
    page.fill(".s-param[data-name=hold]", "10 min")
    page.fill("#s-unit", "SN-WEB-1")
    page.fill("#s-operator", "ana")  # issue 30: the person is named, never the server's login
    page.click("#s-plan")
    until(page, lambda: "long recording" in page.inner_text("#s-plan-text"), "the plan")
    page.click("#s-start")
    page.click("a.started-run")
    page.wait_for_selector("#prompt .question", timeout=30_000)
    assert "Unit mounted" in page.inner_text("#prompt .question")
    # while the prompt waits, the polled thermocouples go on: their plot grows over two updates
    tc = "canvas[data-key='thermocouples/monitor'][data-column=ch101]"
    rows0 = until(page, lambda: _num(page, tc, "data-rows"), "thermocouple rows")
    rows1 = until(page, lambda: _num(page, tc, "data-rows") > rows0 and _num(page, tc, "data-rows"), "a plot update")
    until(page, lambda: _num(page, tc, "data-rows") > rows1, "a second plot update")
    assert page.locator("#interlocks-table").inner_text().count("ok") >= 1
    limits = page.locator("#limits-table").inner_text()
    assert "acs_board odr" in limits and "1 .. 1000 Hz" in limits and "checked" in limits, limits
    page.click("#answer-yes")
    page.wait_for_selector("#prompt", state="detached")
    until(page, lambda: "long recording" in page.inner_text("#live-state"), "the long recording")
    gyro = "canvas[data-key=acs_board][data-column=gyro]"
    g0 = _num(page, gyro, "data-rows")
    g1 = until(page, lambda: _num(page, gyro, "data-rows") > g0 and _num(page, gyro, "data-rows"), "gyro rows")
    until(page, lambda: _num(page, gyro, "data-rows") > g1, "more gyro rows")
    assert int(page.get_attribute(gyro, "data-points")) > 0
    page.click("#stop-btn")
    page.click("#stop-confirm-box-ok")  # issue 30: a stop is confirmed on the page
    page.wait_for_selector("#verdict-word", state="attached")
    until(page, lambda: "aborted" in page.inner_text("#run-status"), "status aborted")
    page.close()

    path = next(station.runs_dir.glob("*web_prompt*.h5"))
    s = read_run_summary(path)
    assert s.status == "aborted" and "web station (web 127.0.0.1)" in s.abort_reason
    assert s.identity["unit_serial"] == "SN-WEB-1"
    operator = [e for e in s.events if e.kind == "operator"]
    answer = [json.loads(e.message) for e in operator if e.source == "prompt"]
    assert answer and answer[0]["answer"] == "yes" and answer[0]["source"] == "web 127.0.0.1"
    assert not [e for e in operator if e.source == "web 127.0.0.1"]  # controls are not answers: a prompt still waits
    stops = [json.loads(e.message) for e in s.events if e.kind == "control" and e.source == "web 127.0.0.1"]
    assert [x["action"] for x in stops] == ["stop"] and stops[0]["origin"] == "web 127.0.0.1"
    assert any(e.kind == "safe_state" for e in s.events)


def test_control_without_the_token_is_refused_and_changes_nothing(station):
    status, body = _request(station.url + "api/start", {"procedure": "web_prompt.yaml"})
    assert status == 401 and "token" in body["errors"][0]
    before = set(station.runs_dir.glob("*.h5"))
    status, _ = _request(station.url + "api/start", {"procedure": "web_prompt.yaml"}, token="wrong-token-123456")
    assert status == 403 and set(station.runs_dir.glob("*.h5")) == before
    status, body = _request(station.url + "api/start", {"procedure": "web_prompt.yaml", "params": {"hold": "10 min"},
                                                         "operator": "ana"}, token=TOKEN)
    assert status == 200, body
    rid = body["id"]
    try:
        _wait(lambda: (_request(station.url + f"api/live?id={rid}")[1].get("control") or {}).get("prompt"), 30, "the prompt")
        for token in (None, "wrong-token-123456"):
            for action, extra in (("stop", {}), ("pause", {"paused": True}), ("answer", {"answer": "no"})):
                status, _ = _request(station.url + f"api/{action}", {"id": rid, **extra}, token=token)
                assert status == (401 if token is None else 403), action
        live = _request(station.url + f"api/live?id={rid}")[1]
        assert live["control"]["running"] and not live["control"]["paused"] and live["control"]["prompt"]
        # an accepted pause goes through the same queue as a refused action would have: once the run
        # file holds it, it would hold them too (the runner writes that queue in order at its check points)
        status, _ = _request(station.url + "api/pause", {"id": rid, "paused": True}, token=TOKEN)
        assert status == 200

        def controls():
            s = read_run_summary(station.runs_dir / rid)
            return s if any(e.kind == "control" for e in s.events) else None

        s = _wait(controls, 30, "the accepted pause in the run file")
        assert s.live_status == "waiting" and not [e for e in s.events if e.kind == "operator"]
        assert [(json.loads(e.message)["action"], e.source) for e in s.events if e.kind == "control"] == [("pause", "web 127.0.0.1")]
        live = _request(station.url + f"api/live?id={rid}")[1]
        assert live["control"]["running"] and live["control"]["paused"] and live["control"]["prompt"]
    finally:
        _request(station.url + "api/stop", {"id": rid}, token=TOKEN)
        _wait(lambda: not _request(station.url + f"api/live?id={rid}")[1]["control"]["running"], 30, "the run to stop")
    assert read_run_summary(station.runs_dir / rid).status == "aborted"


def test_bad_requests_are_refused_with_a_located_line(station):
    status, body = _request(station.url + "api/run?id=../../etc/passwd.h5")
    assert status == 400 and "run id" in body["errors"][0]
    status, body = _request(station.url + "api/start", {"procedure": "web_prompt.yaml", "params": {"hold": "ten minutes"}}, token=TOKEN)
    cli = subprocess.run([sys.executable, "-m", "bench", "validate", str(PROCEDURES / "web_prompt.yaml"), "--config", str(SIM_CONFIG),
                          "-p", "hold=ten minutes"], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert status == 400 and cli.returncode == 2 and body["errors"] == cli.stderr.strip().splitlines(), (body, cli.stderr)
    assert body["errors"][0].startswith("-p hold: ") and "ten minutes" in body["errors"][0]  # issue 30: located at -p
    status, body = _request(station.url + "api/start", {"procedure": "../procedures/x.yaml"}, token=TOKEN)
    assert status == 400 and "procedure" in body["errors"][0]


# ---- runs table, crashed file, a million points ---------------------------------------------------
def test_runs_table_filters(browser, tmp_path):
    runs = tmp_path / "runs"
    make_run_file(runs, unit="SN1", procedure="table_a")
    make_run_file(runs, unit="SN2", procedure="table_b", status="aborted", abort_reason="operator stop")
    make_run_file(runs, unit="SN1", procedure="table_b")
    server = Server(runs)
    try:
        page = _page(browser, server.url)
        page.wait_for_selector("#runs-table")
        assert page.locator("tr.run-row").count() == 3
        page.fill("#f-unit", "SN1")
        page.click("#f-apply")
        until(page, lambda: page.locator("tr.run-row").count() == 2, "2 rows")
        assert {r.get_attribute("data-unit") for r in page.locator("tr.run-row").all()} == {"SN1"}
        page.fill("#f-unit", "")
        page.select_option("#f-status", "aborted")
        page.click("#f-apply")
        until(page, lambda: page.locator("tr.run-row").count() == 1, "1 row")
        assert page.locator("tr.run-row").get_attribute("data-unit") == "SN2"
        page.fill("#f-since", "yesterday")
        page.click("#f-apply")
        until(page, lambda: "since" in page.inner_text("#runs-errors"), "the located error")
        page.goto(server.url + "?procedure=table_b&verdict=incomplete")
        page.wait_for_selector("#runs-table")
        assert page.locator("tr.run-row").count() == 1
        page.click("tr.run-row a")
        page.wait_for_selector("#verdict-word")
        assert page.inner_text("#verdict-word") == "INCOMPLETE"
        page.close()
    finally:
        server.stop()


CRASH_WRITER = textwrap.dedent("""
    import sys, time
    real = time.time
    time.time = lambda: real() - 120.0   # the heartbeat reads 2 minutes old: crashed at once, no 10 s wait
    from pathlib import Path
    from tests.browser import make_run_file
    rec = make_run_file(Path(sys.argv[1]), rows=500, procedure="crash_me", close=False)
    rec.tick(5.0)
    rec.flush()
    print("ready", flush=True)
    time.sleep(60)
""")


def test_run_page_of_a_crashed_file(browser, tmp_path):
    runs = tmp_path / "runs"
    runs.mkdir()
    p = subprocess.Popen([sys.executable, "-c", CRASH_WRITER, str(runs)], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    try:
        assert p.stdout.readline().strip() == "ready"
        p.send_signal(signal.SIGKILL)
        p.wait(timeout=10)
    finally:
        if p.poll() is None:
            p.kill()
    server = Server(runs)
    try:
        page = _page(browser, server.url)
        page.wait_for_selector("tr.run-row")
        assert page.locator("tr.run-row").get_attribute("data-status") == "crashed"
        page.click("tr.run-row a")
        page.wait_for_selector("#verdict-word")
        assert page.inner_text("#run-status") == "crashed"
        assert page.inner_text("#verdict-word") == "INCOMPLETE"
        gyro = "canvas[data-key=board][data-column=gyro]"
        until(page, lambda: _num(page, gyro, "data-updates") >= 1, "the plot")
        assert page.get_attribute(gyro, "data-rows") == "500"
        assert page.locator("#live-panel").count() == 0  # nobody writes it: no live view, no controls
        page.close()
    finally:
        server.stop()


def test_a_million_point_stream_renders_from_a_few_thousand_points(browser, tmp_path):
    runs = tmp_path / "runs"
    make_run_file(runs, rows=1_000_000, procedure="million", rate_hz=1000.0)
    server = Server(runs)
    try:
        page = _page(browser, server.url)
        payloads = []
        page.on("response", lambda r: payloads.append(r) if "/api/stream" in r.url else None)
        page.wait_for_selector("tr.run-row a")
        page.click("tr.run-row a")
        gyro = "canvas[data-key=board][data-column=gyro]"
        until(page, lambda: _num(page, gyro, "data-updates") >= 1, "the plot")
        assert page.get_attribute(gyro, "data-rows") == "1000000"
        bodies = [r.json() for r in payloads if "column=gyro" in r.url]
        assert bodies and all(b["points"] <= 4000 and len(b["t"]) == b["points"] for b in bodies)
        assert not bodies[0]["raw"] and bodies[0]["rows_in_range"] == 1_000_000
        assert 0 < int(page.get_attribute(gyro, "data-points")) <= 3 * 4000
        # zooming in asks for the new range only, still decimated to the plot's width
        payloads.clear()
        page.hover(gyro)
        page.mouse.wheel(0, -500)
        until(page, lambda: _num(page, gyro, "data-updates") >= 2, "the zoomed plot")
        zoomed = [r.json() for r in payloads if "column=gyro" in r.url]
        assert zoomed and zoomed[-1]["rows_in_range"] < 1_000_000 and zoomed[-1]["points"] <= 4000
        page.close()
    finally:
        server.stop()


# ---- without a browser -----------------------------------------------------------------------------
def test_decimation_keeps_every_extreme(tmp_path):
    from bench.record.reader import _open_run
    from bench.web.decimate import StreamCache, column_bins

    path = make_run_file(tmp_path, rows=50_000, rate_hz=100.0)
    t = np.arange(50_000) / 100.0
    gyro_x = np.sin(t / 10.0)
    cache = StreamCache()
    for t0, t1, px in ((None, None, 300), (12.34, 401.7, 97), (100.0, 100.5, 300), (3.0, 499.0, 1)):
        with _open_run(path) as (f, _):
            bins, info = column_bins(f, path, "board", "gyro", t0, t1, px, cache)
        lo, hi = (t[0] if t0 is None else t0), (t[-1] if t1 is None else t1)
        inside = (t >= lo) & (t <= hi)
        assert bins.rows == inside.sum()
        assert np.isclose(np.nanmin(bins.vmin[:, 0]), gyro_x[inside].min()) and np.isclose(np.nanmax(bins.vmax[:, 0]), gyro_x[inside].max())
        assert bins.count[:, 0].sum() == inside.sum() and len(bins.t) <= max(px, 2 * px if bins.raw else px)
        # every bin's extremes are those of the rows whose time falls in it
        if not bins.raw:
            edges = np.searchsorted(t, bins.t)
            stops = np.append(edges[1:], np.searchsorted(t, hi, side="right"))
            for a, b, mn, mx in zip(edges, stops, bins.vmin[:, 0], bins.vmax[:, 0]):
                assert np.isclose(mn, gyro_x[a:b].min()) and np.isclose(mx, gyro_x[a:b].max())
    read_once = cache.rows_read
    with _open_run(path) as (f, _):
        column_bins(f, path, "board", "gyro", None, None, 300, cache)
    assert cache.rows_read - read_once < 2 * 64  # the cached blocks: only the partial edges are read again


def test_run_ids_stay_inside_the_runs_directory(tmp_path):
    from bench.errors import InputError
    from bench.web.paths import run_path

    runs = tmp_path / "runs"
    good = make_run_file(runs)
    outside = make_run_file(tmp_path / "elsewhere")
    (runs / "link.h5").symlink_to(outside)
    assert run_path(runs, good.name) == good.resolve()
    for bad in ("", "/etc/passwd.h5", "../elsewhere/" + outside.name, "link.h5", "a\\b.h5", "x.txt", "missing.h5", "sub/../" + good.name):
        with pytest.raises(InputError):
            run_path(runs, bad)


def test_serve_refuses_bad_options_and_a_taken_port(tmp_path):
    import socket

    def serve(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "bench", "serve", "--runs-dir", str(tmp_path / "runs"), *args],
                              cwd=ROOT, capture_output=True, text=True, timeout=60, env={**os.environ, "BENCH_WEB_TOKEN": ""})

    r = serve("--port", "70000")
    assert r.returncode == 2 and r.stderr.strip().startswith("--port:") and len(r.stderr.strip().splitlines()) == 1
    r = serve("--token", "short")
    assert r.returncode == 2 and r.stderr.strip().startswith("--token:")
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        r = serve("--port", str(taken.getsockname()[1]))
    assert r.returncode == 2 and "in use" in r.stderr and "Traceback" not in r.stderr, r.stderr


@pytest.mark.parametrize("air, mount, state", [(25.0, 24.0, "ok"), (25.0, 106.0, "beyond"), (None, None, "no reading"),
                                               (-46.0, 20.0, "beyond"), (104.0, 20.0, "ok")])
def test_the_chamber_envelope_is_shown_with_its_state(air, mount, state) -> None:
    """The live page's limits: the chamber's set-point limits watched as the lab's envelope (± 5 degC)."""
    from types import SimpleNamespace

    from bench.web.live import limit_states

    last = {"tvac": {k: v for k, v in (("air_temp", air), ("mount_temp", mount)) if v is not None}}
    runner = SimpleNamespace(lab=SimpleNamespace(kinds={"tvac": "tvac"}, config_limits={"tvac": {"set_point": (-40.0, 100.0)}}),
                             procedure=SimpleNamespace(limits={}), monitor=SimpleNamespace(last=last))
    rows = {r["quantity"]: r for r in limit_states(runner)}
    sp = rows["set_point"]
    assert (sp["min"], sp["max"], sp["units"]) == (-40.0, 100.0, "degC")
    assert sp["state"] == state
    if state == "beyond":
        assert sp["value"] in (mount, air) and (sp["value"] > 105 or sp["value"] < -45)


def test_the_rate_tables_limits_show_powers_as_superscripts() -> None:
    """The live page's limits of a rate table: its acceleration limit reads ``0 .. 60 deg/s²`` (the
    units ``deg/s**2`` are the parser's spelling, not a reader's)."""
    from types import SimpleNamespace

    from bench.web.live import limit_states

    runner = SimpleNamespace(lab=SimpleNamespace(kinds={"table": "rate_table"}, config_limits={"table": {}}),
                             procedure=SimpleNamespace(limits={}), monitor=SimpleNamespace(last={}))
    rows = {r["quantity"]: r for r in limit_states(runner)}
    assert rows["accel"]["limits_text"] == "0 .. 60 deg/s²", rows["accel"]
    assert "**" not in " ".join(r["limits_text"] for r in rows.values())
