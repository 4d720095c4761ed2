"""Every test has a time limit, and no test outlives it (issue 33).

pytest-timeout ends a test that runs past its limit (``timeout`` in pyproject.toml, or
``@pytest.mark.timeout(N)``) with a failure and the session goes on; a test its SIGALRM cannot stop
(stuck in C code, or having taken SIGALRM over) ends the session ``HARD_LIMIT_GRACE_S`` later, with
every thread's traceback (tests/conftest.py). Shown here on a throwaway test file run by a pytest
of its own, with the project's settings and conftest and a 2 s grace.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import pytest

from tests.conftest import ROOT

INNER = '''
import signal
import time

import pytest


@pytest.mark.timeout(1)
def test_sleeps_past_its_limit():
    time.sleep(60)


def test_the_next_one_still_runs():
    pass


@pytest.mark.timeout(1)
def test_sleeps_with_the_alarm_ignored():
    signal.signal(signal.SIGALRM, signal.SIG_IGN)  # as a test stuck in C code, or one that took SIGALRM over
    time.sleep(60)


def test_never_reached():
    pass
'''


def test_the_suite_has_a_default_limit() -> None:
    ini = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["pytest"]["ini_options"]
    assert 0 < int(ini["timeout"]) <= 600 and ini["timeout_method"] == "signal"
    assert any(p.startswith("pytest-timeout") for p in ini["required_plugins"])


@pytest.mark.timeout(120)
def test_a_test_past_its_limit_fails_and_one_that_cannot_be_stopped_ends_the_session(tmp_path: Path) -> None:
    inner = tmp_path / "test_inner.py"
    inner.write_text(INNER, encoding="utf-8")
    env = dict(os.environ, BENCH_TEST_HARD_LIMIT_GRACE_S="2", PYTHONUNBUFFERED="1")
    t0 = time.monotonic()
    out = subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-v", "-c", str(ROOT / "pyproject.toml"),
                          "--rootdir", str(ROOT), "-p", "tests.conftest", str(inner)],
                         cwd=ROOT, env=env, capture_output=True, text=True, timeout=100)
    elapsed = time.monotonic() - t0
    text = out.stdout + out.stderr
    assert re.search(r"test_sleeps_past_its_limit FAILED", out.stdout), text[-3000:]
    assert re.search(r"test_the_next_one_still_runs PASSED", out.stdout), text[-3000:]
    # 1 s limit + 2 s grace: faulthandler's dump of every thread, then exit status 1
    assert "Timeout (0:00:03)!" in out.stderr, text[-3000:]
    assert re.search(r'File "[^"]*test_inner\.py", line \d+ in test_sleeps_with_the_alarm_ignored', out.stderr), out.stderr[-3000:]
    assert out.returncode == 1 and "test_never_reached" not in out.stdout, text[-3000:]
    assert elapsed < 60, elapsed  # two 60 s sleeps, cut to about 1 s and 3 s
