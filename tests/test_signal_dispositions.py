"""The suite's signal tests pass when pytest is a background job (issue 33).

``python3 dev.py test &`` in a script, a cron job or a CI wrapper starts pytest with SIGINT and
SIGQUIT ignored (a non-interactive shell does that to every asynchronous command: POSIX.1-2017, Shell
Command Language 2.11 "Signals and Error Handling"), and every program pytest starts inherits it.
``test_ctrl_c_ends_the_live_view_quietly`` then waited forever for a KeyboardInterrupt that never
came. Tests marked ``signals`` now install the dispositions they rely on (tests/conftest.py); here
the real ``/bin/sh`` starts them in the background and they must pass, and without the marker's
dispositions the Ctrl-C test must hang until its time limit ends it.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time

import pytest

from tests.conftest import KEEP_INHERITED_SIGNALS_ENV, ROOT
from tests.programs import find_program

CTRL_C = "tests/test_watch.py::test_ctrl_c_ends_the_live_view_quietly"
SHORT = [  # one test of each way a signal test depends on a disposition; all of them with BENCH_SLOW=1
    CTRL_C,  # in-process: SIGINT must raise KeyboardInterrupt
    "tests/test_startup_signals.py::test_signal_at_a_fixed_delay_after_start[0.5s-SIGINT]",  # a child still starting up
    "tests/test_startup_signals.py::test_signal_as_soon_as_bench_handles_signals[SIGINT]",
    "tests/test_cli_end_to_end.py::test_signal_aborts_to_safe_state[SIGINT]",  # a child with the runner's handlers
]
JOB_TIMEOUT_S = 600.0


def _background_job(*args: str, env: dict[str, str] | None = None, timeout_s: float = JOB_TIMEOUT_S) -> subprocess.CompletedProcess:
    """``ARGS &`` as a non-interactive ``sh`` runs it (then ``wait`` for it): SIGINT and SIGQUIT ignored,
    stdin from /dev/null. Output captured."""
    sh = find_program("sh")
    if sh is None:
        pytest.skip("no POSIX shell (sh) on this machine")
    return subprocess.run([sh, "-c", '"$@" & wait $!', "sh", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=timeout_s, env=env)


def _pytest(*args: str) -> list[str]:
    return [sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-rA", *args]


def test_a_background_job_starts_with_sigint_and_sigquit_ignored() -> None:
    """The premise, on this machine's shell: what the tests below start in the background ignores them."""
    code = "import signal; print(*(signal.getsignal(s) is signal.SIG_IGN for s in (signal.SIGINT, signal.SIGQUIT, signal.SIGTERM)))"
    out = _background_job(sys.executable, "-c", code, timeout_s=60)
    assert out.stdout.split() == ["True", "True", "False"], out


def _passed(out: subprocess.CompletedProcess) -> list[str]:
    """The tests an inner pytest run reports passed (``-rA``); asserts nothing failed, errored or skipped."""
    text = out.stdout + out.stderr
    assert out.returncode == 0, text[-4000:]
    assert not re.search(r"\d+ (failed|error|errors|skipped)\b", text), text[-4000:]
    return re.findall(r"^PASSED (\S+)", out.stdout, re.M)


@pytest.mark.timeout(300)
def test_signal_tests_pass_as_a_background_job() -> None:
    """One signal test of each kind (SHORT) in a background job: they pass."""
    passed = _passed(_background_job(*_pytest(*SHORT)))
    assert passed == SHORT


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_every_signal_test_passes_as_a_background_job() -> None:
    """Every test marked ``signals``, in a background job."""
    marked = [str(p.relative_to(ROOT)) for p in sorted((ROOT / "tests").glob("test_*.py"))
              if "mark.signals" in p.read_text(encoding="utf-8") and p.name != "test_signal_dispositions.py"]
    out = _background_job(*_pytest("-m", "signals", *marked), timeout_s=850)
    passed = _passed(out)
    assert CTRL_C in passed and len(passed) >= 20, passed  # 20 when this was written
    assert re.search(rf"\b{len(passed)} passed, \d+ deselected", out.stdout), out.stdout[-2000:]


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_without_its_dispositions_the_ctrl_c_test_hangs_until_its_time_limit() -> None:
    """The bug of the issue, kept from hanging by the time limit: with the inherited (ignored) SIGINT,
    ``bench watch`` never sees its Ctrl-C (the test takes 0.5 s otherwise); pytest-timeout ends it
    after 20 s, inside the live view, with its stack. (Slow: 20 s spent waiting on purpose.)"""
    env = dict(os.environ, **{KEEP_INHERITED_SIGNALS_ENV: "1"})
    t0 = time.monotonic()
    out = _background_job(*_pytest("--timeout", "20", CTRL_C), env=env, timeout_s=150)
    elapsed = time.monotonic() - t0
    text = out.stdout + out.stderr
    assert out.returncode == 1 and re.search(r"\b1 failed\b", text), text[-4000:]
    assert "Timeout (>20.0s) from pytest-timeout" in text, text[-4000:]
    assert re.search(r"^bench/watch\.py:\d+: Failed$", text, re.M), text[-4000:]  # ended inside the live view
    assert elapsed < 120, elapsed
