"""SIGINT, SIGTERM and SIGHUP in the first seconds of `bench run` (issue 21, part 2): one line and
exit code 1, no traceback, and either no run file or one that opens with status `aborted`.

Each case starts `bench run --sim --realtime` (a dry-run on the simulators, recording far longer than
the test lasts) and sends one signal: at fixed delays after the start, while the process starts up
before any file exists, and in the window where the run file exists but recording has not started
(found by polling for the file's appearance).
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bench.record import read_run_summary
from bench.record.space import RESERVE_SUFFIX
from bench.startup_signals import STOP_SIGNALS, StartupSignals, StoppedDuringStartup
from tests.conftest import ROOT, SIM_CONFIG, write_procedure

pytestmark = pytest.mark.signals  # every test here delivers stop signals

STARTUP_ABORT = "stopped during start-up by"


def _caught(pid: int) -> set[int]:
    """Signals the process ``pid`` has a handler for (``SigCgt`` of /proc/PID/status)."""
    try:
        text = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return set()
    mask = int(next(line.split()[1] for line in text.splitlines() if line.startswith("SigCgt:")), 16)
    return {s for s in range(1, 65) if mask >> (s - 1) & 1}


def _start(tmp_path: Path) -> tuple[subprocess.Popen, Path, float]:
    proc = write_procedure(
        tmp_path / "startup.yaml",
        "  - power: {instrument: acs_board, on: true}\n  - record: {instrument: acs_board, duration: 120 s}\n",
        instruments="[acs_board, tvac]",
    )
    runs = tmp_path / "runs"
    t0 = time.monotonic()
    p = subprocess.Popen(
        [sys.executable, "-m", "bench", "run", str(proc), "--config", str(SIM_CONFIG), "--sim", "--realtime",
         "--runs-dir", str(runs)],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    return p, runs, t0


def _wait(p: subprocess.Popen, until, timeout_s: float = 30.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not until():
        if p.poll() is not None:
            raise AssertionError(f"bench run ended before the signal: {p.communicate()}")
        if time.monotonic() > deadline:
            p.kill()
            raise AssertionError(f"condition not reached within {timeout_s} s")
        time.sleep(0.001)


def _stop_and_check(p: subprocess.Popen, runs: Path, sig: signal.Signals) -> str:
    """Send ``sig``; assert the documented ending. Returns where the signal landed."""
    p.send_signal(sig)
    try:
        out, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
    assert "Traceback" not in out + err, err[-3000:]
    assert p.returncode == 1, (p.returncode, out[-2000:], err[-2000:])
    files = sorted(runs.glob("*.h5")) if runs.exists() else []
    assert len(files) <= 1, files
    assert not list(runs.glob(f".*{RESERVE_SUFFIX}")) if runs.exists() else True
    if not files:
        assert err.strip() == f"bench: stopped during start-up by {sig.name}; no run file was created", err
        return "before the run file"
    s = read_run_summary(files[0], stale_after_s=0)  # opens with the project's reader
    assert s.status == "aborted", (s.status, s.abort_reason)
    if s.abort_reason.startswith(STARTUP_ABORT):
        assert s.abort_reason.startswith(f"{STARTUP_ABORT} {sig.name} (while ")
        assert err.strip() == f"bench: stopped during start-up by {sig.name}; run file {files[0]} closed with status aborted", err
        return "start-up, file aborted"
    assert sig.name in s.abort_reason and "operator stop" in s.abort_reason, s.abort_reason
    assert "safe_state" in {e.kind for e in s.events}
    return "run handlers, aborted to the safe state"


@pytest.mark.parametrize("delay_s,sig", [(0.2, signal.SIGTERM), (0.5, signal.SIGINT), (0.5, signal.SIGHUP),
                                         (1.0, signal.SIGTERM), (1.0, signal.SIGINT)],
                         ids=["0.2s-SIGTERM", "0.5s-SIGINT", "0.5s-SIGHUP", "1.0s-SIGTERM", "1.0s-SIGINT"])
def test_signal_at_a_fixed_delay_after_start(tmp_path: Path, delay_s: float, sig: signal.Signals) -> None:
    p, runs, t0 = _start(tmp_path)
    time.sleep(max(0.0, t0 + delay_s - time.monotonic()))
    print(_stop_and_check(p, runs, sig))


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="reads the caught signals from /proc (Linux)")
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_signal_as_soon_as_bench_handles_signals(tmp_path: Path, sig: signal.Signals) -> None:
    """0.05 s after bench's first code ran (its start-up handler is in place: seen in SigCgt),
    while Python still imports bench. Before that only Python itself runs (site import), which no
    program can guard."""
    p, runs, _ = _start(tmp_path)
    _wait(p, lambda: set(STOP_SIGNALS) <= _caught(p.pid))
    time.sleep(0.05)
    print(_stop_and_check(p, runs, sig))


@pytest.mark.parametrize("after_s,sig", [(0.0, signal.SIGTERM), (0.0, signal.SIGINT), (0.02, signal.SIGTERM),
                                         (0.1, signal.SIGINT)],
                         ids=["+0s-SIGTERM", "+0s-SIGINT", "+0.02s-SIGTERM", "+0.1s-SIGINT"])
def test_signal_once_the_run_file_exists(tmp_path: Path, after_s: float, sig: signal.Signals) -> None:
    """The run file exists but recording has not started (file created, instruments being opened)."""
    p, runs, _ = _start(tmp_path)
    _wait(p, lambda: runs.exists() and any(runs.glob("*.h5")))
    time.sleep(after_s)
    where = _stop_and_check(p, runs, sig)
    print(where)
    assert where != "before the run file"


def test_guard_defers_a_signal_inside_held_blocks_and_hands_over() -> None:
    """In-process: a signal inside held() is raised after it, once; after hand_over only noted."""
    before = {s: signal.getsignal(s) for s in STOP_SIGNALS}
    try:
        guard = StartupSignals.install()
        try:
            with pytest.raises(StoppedDuringStartup, match="SIGTERM; no run file was created"):
                with guard.held():
                    signal.raise_signal(signal.SIGTERM)
                    assert guard.received == "SIGTERM"  # noted, not raised inside the block
                guard.raise_pending()
            signal.raise_signal(signal.SIGINT)  # a second signal is only noted
            guard.raise_pending()  # and the first is not raised twice
            assert guard.received == "SIGTERM"
        finally:
            guard.uninstall()
        assert signal.getsignal(signal.SIGTERM) == signal.SIG_IGN  # after a stop, further ones are ignored

        for s, h in before.items():
            signal.signal(s, h)
        guard = StartupSignals.install()
        try:
            guard.hand_over()
            signal.raise_signal(signal.SIGTERM)
            assert guard.signum == signal.SIGTERM  # for the runner's handlers to act on
        finally:
            guard.uninstall()
    finally:
        for s, h in before.items():
            signal.signal(s, h)


def test_start_run_interrupted_while_opening_the_lab_finalises_the_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A KeyboardInterrupt (no start-up handler: a run started by `bench soak` or a library user)
    while the instruments open: the file is closed as aborted, readable."""
    from bench.config import load_config
    from bench.procedure.loader import load_procedure
    from bench.runner import session as session_mod
    from bench.runner.operator import Operator

    def interrupted(*_a, **_k):
        raise KeyboardInterrupt

    monkeypatch.setattr(session_mod, "open_lab", interrupted)
    proc = load_procedure(write_procedure(tmp_path / "p.yaml", "  - power: {instrument: acs_board, on: true}\n"))
    runs = tmp_path / "runs"
    with pytest.raises(KeyboardInterrupt):
        session_mod.start_run(proc, load_config(SIM_CONFIG), procedure_path=tmp_path / "p.yaml", config_path=SIM_CONFIG,
                              runs_dir=runs, sim=True, realtime=False, operator=Operator(None, None), progress=None)
    (path,) = runs.glob("*.h5")
    s = read_run_summary(path)
    assert s.status == "aborted"
    assert s.abort_reason == "stopped during start-up by KeyboardInterrupt (while opening the instruments)"


FINALISER_SCRIPT = """
import gc, os, signal, sys, time, weakref

import bench.cli
from bench.__main__ import entry

where = sys.argv[1]


def stop_inside_a_finaliser():
    os.kill(os.getpid(), signal.SIGTERM)
    for _ in range(100_000):  # the handler runs here, inside the finaliser
        pass


class Held:
    def __del__(self):
        if where == "__del__ in a GC cycle":
            stop_inside_a_finaliser()


class Unrelated:
    def __del__(self):
        raise ValueError("an unrelated finaliser error")  # must still be reported by Python


def main(argv=None):
    Unrelated()
    if where == "weakref callback":
        obj = Held()
        weakref.finalize(obj, stop_inside_a_finaliser)
        del obj  # the callback runs here (reference count)
    else:
        a, b = Held(), Held()
        a.other, b.other = b, a  # a cycle: only the garbage collector frees it
        del a, b
        gc.collect()
    time.sleep(20)  # the start-up goes on (a blocking call): the stop must land in it
    print("the stop signal was lost", flush=True)
    return 0


bench.cli.main = main
sys.exit(entry())
"""


@pytest.mark.parametrize("where", ["weakref callback", "__del__ in a GC cycle"])
def test_a_stop_signal_inside_a_finaliser_ends_as_documented(tmp_path: Path, where: str) -> None:
    """A stop signal handled while Python runs a finaliser (a weakref callback, ``__del__`` run by the
    garbage collector: SQLAlchemy and h5py clean up that way) used to raise there, where Python prints
    "Exception ignored … Traceback" and drops the exception, and the stop was lost. Now: the documented
    line and exit 1, and an unrelated finaliser's error is still reported."""
    script = tmp_path / "finaliser.py"
    script.write_text(FINALISER_SCRIPT)
    r = subprocess.run([sys.executable, str(script), where], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 1 and r.stdout == "", (r.returncode, r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert lines[-1] == "bench: stopped during start-up by SIGTERM; no run file was created", r.stderr
    assert "StoppedDuringStartup" not in r.stderr and "stopped during start-up" not in "\n".join(lines[:-1]), r.stderr
    assert "ValueError: an unrelated finaliser error" in r.stderr  # other unraisable errors: Python's own report


WRAPPED_STOP_SCRIPT = """
import os, signal, sys

import bench.runner.session as session
from bench.__main__ import entry


def open_lab_importing_an_extension(*_a, **_k):
    # what a pybind11 extension module (scipy, matplotlib) does when an exception is raised while it
    # initialises (pybind11's PYBIND11_CATCH_INIT_EXCEPTIONS: raise_from(e, PyExc_ImportError,
    # "initialization failed")): the stop signal's exception comes out as an ImportError raised from it
    try:
        os.kill(os.getpid(), signal.SIGTERM)
        for _ in range(1_000_000):  # the handler runs here
            pass
    except BaseException as exc:
        raise ImportError("initialization failed") from exc
    raise AssertionError("the stop signal was lost")


session.open_lab = open_lab_importing_an_extension
sys.argv = ["bench", "run", *sys.argv[1:]]
sys.exit(entry())
"""


def test_a_stop_turned_into_a_library_error_while_the_instruments_open_is_still_the_stop(tmp_path: Path) -> None:
    """CI failure of 2026-11-28: SIGTERM 1.0 s after the start landed while opening the instruments
    imported a pybind11 extension, which raised ``ImportError: initialization failed`` from the
    stop; the run file was closed as "instruments could not be opened: initialization failed".
    The stop is found in the error's chain: the run file is closed as stopped by SIGTERM, one line."""
    proc = write_procedure(tmp_path / "p.yaml", "  - power: {instrument: acs_board, on: true}\n", instruments="[acs_board, tvac]")
    runs = tmp_path / "runs"
    script = tmp_path / "wrapped.py"
    script.write_text(WRAPPED_STOP_SCRIPT)
    r = subprocess.run([sys.executable, str(script), str(proc), "--config", str(SIM_CONFIG), "--sim", "--runs-dir", str(runs)],
                       cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert "Traceback" not in r.stderr and r.returncode == 1, (r.returncode, r.stdout, r.stderr)
    (path,) = runs.glob("*.h5")
    s = read_run_summary(path, stale_after_s=0)
    assert (s.status, s.abort_reason) == ("aborted", "stopped during start-up by SIGTERM (while opening the instruments)")
    assert r.stderr.strip() == f"bench: stopped during start-up by SIGTERM; run file {path} closed with status aborted", r.stderr
