"""A real browser for the web station's tests: Debian's chromium driven by Playwright for Python.

Playwright is given the system browser (``executable_path``): its own browser download cannot be
reached here. Tests that need it are skipped, with the reason, where chromium or playwright is
missing (``dev.py`` installs chromium with apt-get; playwright is a test dependency).
"""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Iterator

import pytest

from tests.programs import find_program

ROOT = Path(__file__).resolve().parents[1]
TOKEN = "web-test-token-0123456789"
START_TIMEOUT_S = 30.0


def chromium_path() -> str:
    """The system chromium, or skip the test saying why."""
    exe = find_program("chromium") or find_program("chromium-browser")
    if exe is None:
        pytest.skip("chromium is not installed (apt-get install chromium; 'python dev.py' installs it)")
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        pytest.skip("playwright is not installed (pip install -e '.[test]')")
    return exe


def launch_browser() -> Iterator[object]:
    """A headless chromium (Playwright ``Browser``) for the duration of the generator."""
    exe = chromium_path()
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=exe, args=["--no-sandbox", "--disable-gpu"], headless=True)
        try:
            yield browser
        finally:
            browser.close()


class Server:
    """``bench serve`` in a subprocess on a free port of 127.0.0.1; ``url`` ends with ``/``."""

    def __init__(self, runs_dir: Path, *extra: str):
        self.runs_dir = runs_dir
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "bench", "serve", "--runs-dir", str(runs_dir), "--port", "0", "--token", TOKEN, *extra],
            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + START_TIMEOUT_S
        line = ""
        while time.monotonic() < deadline:
            line = self.proc.stdout.readline()
            m = re.match(r"bench serve: (http://\S+/)", line)
            if m:
                self.url = m.group(1)
                return
            if self.proc.poll() is not None:
                break
        self.stop()
        raise AssertionError(f"bench serve did not start: {line!r} {self.proc.stderr.read() if self.proc.stderr else ''}")

    def stop(self) -> str:
        """SIGINT (as Ctrl-C), then kill after 30 s; returns stderr."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=10)
        return self.proc.stderr.read() if self.proc.stderr else ""



def make_run_file(runs_dir: Path, *, rows: int = 200, unit: str = "", procedure: str = "web_table", status: str = "completed",
                  abort_reason: str = "", rate_hz: float = 100.0, close: bool = True):
    """A run file written with the project's recorder: one 3-axis ``gyro`` stream (deg/s) and a
    ``temp`` column (degC) of ``rows`` rows at ``rate_hz``, a step, closed with ``status`` (or left
    open with ``close=False``; returns the recorder then, else the file's path)."""
    import numpy as np

    from bench.record import Column, RunRecorder

    rec = RunRecorder.create(runs_dir, procedure_name=procedure, procedure_text=f"name: {procedure}\n", procedure_path=f"{procedure}.yaml",
                             config_text="name: test\n", config_path="test.yaml", mode="sim", software_version="test",
                             identity={"unit_serial": unit} if unit else None)
    key = rec.add_stream("board", [Column("gyro", "deg/s", "f8", (3,)), Column("temp", "degC", "f8")], rate_hz=rate_hz)
    rec.start()
    rec.event("run_start", "runner", f"{procedure}: 1 steps, mode sim", t_s=0.0)
    rec.event("step_start", "record", "recording", t_s=0.0, step=0)
    chunk = 100_000
    for a in range(0, rows, chunk):
        t = np.arange(a, min(rows, a + chunk)) / rate_hz
        gyro = np.stack([np.sin(t / 10.0), np.cos(t / 10.0), 0.01 * t], axis=1)
        rec.append(key, t, gyro=gyro, temp=20.0 + 0.001 * t)
        rec.flush()
    t_end = rows / rate_hz
    if not close:
        return rec
    rec.event("step_end", "record", "done" if status == "completed" else f"aborted: {abort_reason}", t_s=t_end, step=0)
    rec.tick(t_end)
    rec.close(status, abort_reason)
    return rec.path
