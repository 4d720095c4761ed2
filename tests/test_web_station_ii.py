"""Operator's station II (issue 30), the web side, in a real browser (Debian's chromium driven by
Playwright, tests/browser.py) at 1400 px and at 1024x768: one server and one browser for the module.

The runs directory is tests/unit_runs.py's (several units, dry-runs mixed in, stand-ins for hardware
runs said there), to which the tests add live runs started from the page and one `bench run` in a
terminal. Skipped, with the reason, where chromium or playwright is missing.
"""

from __future__ import annotations

import json
import os
import pty
import re
import shutil
import subprocess
import sys
import threading

import h5py
import pytest

from bench.record import read_run_summary
from tests.browser import ROOT, TOKEN, Server, launch_browser
from tests.test_web_station import _until

PROCEDURES = ROOT / "tests" / "data" / "procedures"
SIM_CONFIG = ROOT / "configs" / "sim.yaml"
BANNER = "DRY-RUN: simulated instruments, not acceptance evidence"
WIDE, NARROW = {"width": 1400, "height": 900}, {"width": 1024, "height": 768}


@pytest.fixture(scope="module")
def browser():
    yield from launch_browser()


@pytest.fixture(scope="module")
def station(unit_runs, tmp_path_factory):
    runs = tmp_path_factory.mktemp("web2") / "runs"
    shutil.copytree(unit_runs, runs, ignore=shutil.ignore_patterns("catalog.sqlite*"))  # catalogued again from the copies
    server = Server(runs, "--procedures", str(PROCEDURES), "--config", str(SIM_CONFIG))
    yield server
    err = server.stop()
    assert "Traceback" not in err, err


def _page(browser, url: str, viewport=WIDE):
    page = browser.new_page(viewport=viewport)
    page.set_default_timeout(20_000)
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.errors = errors
    page.goto(url)
    return page


def _drain(fd: int) -> None:
    try:
        while os.read(fd, 4096):
            pass
    except OSError:
        pass


def _fits(page, selector: str) -> bool:
    """Whether the element's right edge lies inside the viewport (no horizontal scrolling needed)."""
    box = page.locator(selector).bounding_box()
    return box is not None and box["x"] + box["width"] <= page.viewport_size["width"] + 0.5


# ---- the runs list and a unit's history ----------------------------------------------------------------
def test_runs_list_tells_dry_runs_apart_and_fits_1024(browser, station):
    page = _page(browser, station.url, NARROW)
    page.wait_for_selector("#runs-table")
    rows = page.locator("tr.run-row")
    modes = [r.get_attribute("data-mode") for r in rows.all()]
    assert modes.count("sim") == 3 and modes.count("hardware") == 7, modes
    for r in rows.all():
        cls, text = r.get_attribute("class"), r.inner_text()
        dry = r.get_attribute("data-mode") == "sim"
        assert ("not-evidence" in cls) == dry and ("DRY-RUN" in text) == dry and ("passed (dry-run)" in text) == dry
    assert _fits(page, "#runs-table"), "the runs table overflows at 1024 px"
    page.select_option("#f-mode", "dry-run")
    page.click("#f-apply")
    _until(page, lambda: page.locator("tr.run-row").count() == 3, "the dry-runs only")
    assert "mode=dry-run" in page.url
    assert not page.errors
    page.close()


def test_a_units_page_shows_its_history_and_its_lot(browser, station):
    page = _page(browser, station.url + "unit?serial=SN12")
    page.wait_for_selector("#figures .figure")
    assert page.inner_text("#mode-banner").startswith("1 of 3 runs of SN12 are DRY-RUNs")
    runs = page.locator("#unit-runs tr.unit-run")
    assert [r.get_attribute("data-mode") for r in runs.all()] == ["sim", "hardware", "hardware"]
    bias = page.locator(".figure[data-name='gyro z bias']")
    assert bias.get_attribute("data-outlier") == "1" and "OUTLIER of its lot" in bias.inner_text()
    assert (bias.locator("canvas.by-date").get_attribute("data-real"), bias.locator("canvas.by-date").get_attribute("data-dry")) == ("2", "1")
    assert bias.locator("canvas.by-lot").get_attribute("data-units") == "5"
    assert page.locator(".figure[data-name='gyro z scale-factor error']").get_attribute("data-outlier") == "0"
    assert page.get_attribute("#unit-package", "href") == "/api/unit_package?serial=SN12"  # its content: test_station_ii.py
    page.set_viewport_size(NARROW)
    _until(page, lambda: _fits(page, "#figures"), "the figures at 1024 px")
    assert not page.errors
    page.close()


def test_run_pages_carry_the_banner_of_a_dry_run_only(browser, station):
    modes = {p.name: h5py.File(p, "r").attrs["mode"] for p in station.runs_dir.glob("*.h5")}
    dry = next(n for n, m in modes.items() if m == "sim")
    real = next(n for n, m in modes.items() if m == "hardware")
    page = _page(browser, station.url + f"run?id={dry}")
    page.wait_for_selector("#verdict-word")
    assert page.inner_text("#mode-banner") == BANNER
    assert "not-evidence" in page.get_attribute("#verdict-box", "class") and page.inner_text("#verdict-word") == "PASSED"
    assert "DRY-RUN: not acceptance evidence" in page.inner_text("#verdict-mode")
    checks = page.inner_text("#checks-table")
    assert re.search(r"sf_z\s.*\d %\s+-5 \.\. 5 %", checks) and "-0.4 .. 0.4 deg/s" in checks
    page.goto(station.url + f"run?id={real}")
    page.wait_for_selector("#verdict-word")
    assert page.locator("#mode-banner").count() == 0 and "PASSED" in page.get_attribute("#verdict-box", "class")
    page.close()


# ---- a live run from the page ------------------------------------------------------------------------
def test_live_run_operator_prompt_pause_stop_units_and_plots(browser, station):
    page = _page(browser, station.url + "start?procedure=web_live.yaml")
    page.fill("#token-input", TOKEN)
    page.click("#token-save")
    page.wait_for_selector("#token-state.ok")
    page.wait_for_selector("#s-params .param-row")
    assert "DRY-RUN" in page.inner_text("#s-lab") and "1 operator prompt" in page.inner_text("#s-info")
    hold = page.locator(".param-row").filter(has=page.locator("[data-name=hold]"))
    assert page.input_value("[data-name=hold]") == "" and "default 2 h" in hold.inner_text() and "paused and stopped" in hold.inner_text()
    page.uncheck("#s-realtime")  # virtual time: the recordings take no wall time; the prompt and a pause hold it
    page.fill("[data-name=hold]", "20 h")  # still recording when stopped, however loaded the machine
    page.click("#s-start")
    _until(page, lambda: "operator" in page.inner_text("#s-errors"), "the operator is required")
    page.fill("#s-operator", "alice")
    page.fill("#s-unit", "SN-LIVE")
    page.click("#s-start")
    page.click("a.started-run")
    page.wait_for_selector("#prompt .question", timeout=30_000)
    assert page.inner_text("#mode-banner") == BANNER and page.inner_text("#operator") == "alice (web 127.0.0.1)"
    assert "no aborts the run" in page.inner_text("#prompt .question")
    # a typo is refused at the prompt itself, and the box is cleared
    page.fill("#answer-text", "yse")
    page.click("#answer-send")
    _until(page, lambda: "not an accepted answer" in page.inner_text("#prompt-error"), "the refusal at the prompt")
    assert page.input_value("#answer-text") == ""
    # "No" asks first; going back leaves the question waiting
    page.click("#answer-no")
    page.wait_for_selector("#no-confirm-box")
    assert "stops the run" in page.inner_text("#no-confirm-box")
    page.screenshot(path=str(station.runs_dir.parent / "web-prompt.png"))
    page.click("#no-confirm-box-cancel")
    assert page.locator("#prompt .question").count() == 1
    # the interlocks and limits in their units, the live readings too
    interlocks = page.inner_text("#interlocks-table")
    assert "-33 .. 70 degC" in interlocks and re.search(r"\d degC\s+ok", interlocks) and "no gap in the frames longer than 2 s" in interlocks
    assert re.search(r"rate_table angle \S+ deg, rate 5 deg/s", page.inner_text("#readings"))
    page.click("#answer-yes")
    page.wait_for_selector("#prompt", state="detached")
    _until(page, lambda: "long recording" in page.inner_text("#live-state"), "the long recording")
    # pause: it looks paused, and virtual time stands still
    page.click("#pause-btn")
    _until(page, lambda: "paused" in page.inner_text("#run-status"), "the paused badge")
    assert page.inner_text("#live-word") == "PAUSED" and page.inner_text("#pause-btn") == "Resume"
    page.wait_for_timeout(1300)  # the file's run time is at most one flush (1 s of wall time) behind the runner
    t0 = page.inner_text("#live-run-time")
    page.wait_for_timeout(1200)  # the defect: about 2,400 s of run time per second of wall time
    assert page.inner_text("#live-run-time") == t0, "run time went on while paused"
    page.screenshot(path=str(station.runs_dir.parent / "web-paused.png"), full_page=True)
    page.set_viewport_size(NARROW)
    page.screenshot(path=str(station.runs_dir.parent / "web-paused-1024.png"))
    page.set_viewport_size(WIDE)
    page.click("#pause-btn")
    _until(page, lambda: page.inner_text("#live-run-time") != t0, "the run going on again")
    _until(page, lambda: page.locator("canvas[data-time-axis=hms]").count() > 0, "an h:mm:ss time axis past 10 minutes")
    # the plots: one per unit of a stream, gaps left open, status words apart, following the window
    tc = page.locator("canvas[data-key='thermocouples/monitor']")
    assert tc.count() == 1 and tc.get_attribute("data-columns") == "ch101,ch102,ch103,ch104"
    gyro = "canvas[data-key=acs_board][data-column=gyro]"
    _until(page, lambda: int(page.get_attribute(gyro, "data-gaps") or 0) >= 1, "the gap between the board's windows")
    assert page.locator("canvas[data-key='rate_table/monitor'][data-column=statusword]").get_attribute("data-status") == "1"
    wide = int(page.get_attribute(gyro, "data-width"))
    page.set_viewport_size(NARROW)
    _until(page, lambda: int(page.get_attribute(gyro, "data-width")) < wide - 300, "the plots to follow the window")
    page.set_viewport_size(WIDE)
    # stop: asked first; "keep running" keeps it running
    page.click("#stop-btn")
    page.wait_for_selector("#stop-confirm-box")
    page.click("#stop-confirm-box-cancel")
    page.wait_for_timeout(600)
    assert "aborted" not in page.inner_text("#run-status") and page.is_visible("#stop-btn")
    page.click("#stop-btn")
    page.click("#stop-confirm-box-ok")
    _until(page, lambda: "aborted" in page.inner_text("#run-status"), "the stop")
    assert page.is_hidden("#controls")
    _until(page, lambda: page.inner_text("#ended") not in ("", "—"), "the end time, without a reload")
    size = page.inner_text("#file-size")
    assert size.endswith("MB") or size.endswith("kB")
    assert not page.errors
    page.close()

    path = next(p for p in station.runs_dir.glob("*web_live*.h5"))
    with h5py.File(path, "r") as f:
        assert (f.attrs["operator"], f.attrs["operator_origin"]) == ("alice", "web 127.0.0.1")
    s = read_run_summary(path)
    answers = [json.loads(e.message) for e in s.events if e.kind == "operator" and e.source == "prompt"]
    assert [(a["answer"], a["operator"], a["source"]) for a in answers] == [("yes", "alice", "web 127.0.0.1")]  # the typo never reached the run
    controls = [json.loads(e.message) for e in s.events if e.kind == "control"]
    assert [(c["action"], c["operator"], c["origin"]) for c in controls] == [
        ("pause", "alice", "web 127.0.0.1"), ("resume", "alice", "web 127.0.0.1"), ("stop", "alice", "web 127.0.0.1")]
    assert s.status == "aborted" and s.attrs["operator"] == "alice"


def test_a_terminal_run_waiting_at_a_prompt_is_listed_as_waiting(browser, station, tmp_path):
    """A `bench run` in a terminal (a pseudo-terminal here) at its prompt: `waiting`, with its run time."""
    proc = tmp_path / "door.yaml"
    proc.write_text("schema: bench-procedure/1\nname: door\ninstruments: [acs_board]\nsteps:\n  - wait: 90 s\n"
                    "  - prompt: {id: door, text: Close the door}\n")
    master, slave = pty.openpty()
    p = subprocess.Popen([sys.executable, "-m", "bench", "run", str(proc), "--config", str(SIM_CONFIG), "--sim", "--runs-dir",
                          str(station.runs_dir), "--unit", "SN-TTY"], cwd=ROOT, stdin=slave, stdout=slave, stderr=slave, close_fds=True)
    os.close(slave)
    reader = threading.Thread(target=_drain, args=(master,), daemon=True)  # the terminal reads what the run prints
    reader.start()
    try:
        page = _page(browser, station.url + "?unit=SN-TTY")

        def waiting() -> bool:
            if page.locator("tr.run-row").count() == 1 and page.locator("tr.run-row").get_attribute("data-status") == "waiting":
                return True
            page.wait_for_timeout(700)
            page.reload()
            page.wait_for_selector("#runs-count")
            return False

        _until(page, waiting, "the waiting terminal run", timeout_s=45)
        row = page.inner_text("tr.run-row")
        assert "0:01:30" in row and "Close the door" in row, row
        page.close()
        os.write(master, b"yes\n")
        assert p.wait(timeout=60) == 0
    finally:
        if p.poll() is None:
            p.kill()
        os.close(master)
