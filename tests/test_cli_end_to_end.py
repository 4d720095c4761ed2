"""`bench run` and `bench inspect` end to end, in subprocesses, as an operator would use them."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from bench import __version__
from bench.record import read_run_summary, read_stream
from tests.conftest import ROOT, SIM_CONFIG, STARTUP, run_cli, write_procedure


def _only_run_file(runs: Path) -> Path:
    files = sorted(runs.glob("*.h5"))
    assert len(files) == 1, files
    return files[0]


def test_version():
    r = run_cli("--version")
    assert r.returncode == 0 and r.stdout.strip() == f"bench {__version__}"


def test_startup_profile_dry_run_and_inspect(tmp_path):
    runs = tmp_path / "runs"
    r = run_cli("run", str(STARTUP), "--config", str(SIM_CONFIG), "--sim", "--runs-dir", str(runs))
    assert r.returncode == 0, r.stdout + r.stderr
    assert "COMPLETED" in r.stdout
    path = _only_run_file(runs)
    assert path.name.endswith("_startup_profile.h5")
    s = read_run_summary(path)
    assert s.status == "completed"
    assert s.procedure_text == STARTUP.read_text()
    assert s.config_text == SIM_CONFIG.read_text()
    assert s.instruments["acs_board"]["serial"] == "SIM-0001"
    (stream,) = s.streams
    assert stream.rows == 180_000  # 30 min at 100 Hz
    assert stream.rate_hz == pytest.approx(100.0, rel=1e-3)
    assert stream.t_end_s - stream.t_start_s == pytest.approx(1800.0, abs=0.02)
    assert [st.outcome for st in s.steps] == ["done", "done", "done", "done", "passed", "done"]
    kinds = {e.kind for e in s.events}
    assert {"run_start", "step_start", "step_end", "command", "reply", "run_end"} <= kinds
    commands = [e.data for e in s.events if e.kind == "command"]
    assert commands[0][:3] == b"\xa5\x5a\x10"  # IDENTIFY frame, raw bytes kept for replay
    with h5py.File(path, "r") as f:
        assert f["streams/acs_board/gyro"].attrs["units"] == "deg/s"
        assert f["streams/acs_board/gyro"].shape == (180_000, 3)

    r = run_cli("inspect", str(path))
    assert r.returncode == 0, r.stderr
    for needle in ("startup_profile", "completed", "acs_board", "gyro", "deg/s", "built-in test", "step_end", "180000"):
        assert needle in r.stdout, needle


def test_failed_bit_is_exit_1_and_recorded(tmp_path):
    config = tmp_path / "lab.yaml"
    config.write_text(SIM_CONFIG.read_text().replace("serial: SIM-0001", "serial: SIM-0001\n      bit_fail_mask: 4").replace("sensors/", str(ROOT / "configs" / "sensors") + "/"))
    proc = write_procedure(tmp_path / "bitcheck.yaml", "  - power: {instrument: acs_board, on: true}\n  - bit: {instrument: acs_board}\n")
    r = run_cli("run", str(proc), "--config", str(config), "--sim", "--runs-dir", str(tmp_path / "runs"))
    assert r.returncode == 1, r.stdout + r.stderr
    assert "FAILED" in r.stdout and "0x0004" in r.stdout
    s = read_run_summary(_only_run_file(tmp_path / "runs"))
    assert s.status == "completed" and s.steps[-1].outcome == "failed"


def test_bad_procedure_exit_2_one_line_per_error(tmp_path):
    proc = write_procedure(tmp_path / "bad.yaml", "  - record: {instrument: acs_board, duration: 3 kg}\n  - warp: {}\n")
    r = run_cli("run", str(proc), "--config", str(SIM_CONFIG), "--sim", "--runs-dir", str(tmp_path / "runs"))
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 2 and "Traceback" not in r.stderr
    assert lines[0].startswith(f"{proc}:5:") and "duration" in lines[0]
    assert lines[1].startswith(f"{proc}:6:") and "warp" in lines[1]
    assert not (tmp_path / "runs").exists()  # nothing started


def test_missing_files_and_instruments_exit_2(tmp_path):
    r = run_cli("run", str(tmp_path / "nope.yaml"), "--config", str(SIM_CONFIG), "--sim")
    assert r.returncode == 2 and "procedure not found" in r.stderr and "Traceback" not in r.stderr
    proc = write_procedure(tmp_path / "p.yaml", "  - wait: {duration: 1 s}\n", instruments="[chamber]")
    r = run_cli("run", str(proc), "--config", str(SIM_CONFIG), "--sim", "--runs-dir", str(tmp_path / "runs"))
    assert r.returncode == 2 and f"{proc}:3:" in r.stderr and "'chamber'" in r.stderr
    r = run_cli("inspect", str(tmp_path / "nope.h5"))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    r = run_cli("run", str(proc))
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1


def test_unwritable_destination_refused_before_run(tmp_path):
    r = run_cli("run", str(STARTUP), "--config", str(SIM_CONFIG), "--sim", "--runs-dir", "/dev/null/runs")
    assert r.returncode == 2, r.stdout + r.stderr
    assert "/dev/null/runs" in r.stderr and "Traceback" not in r.stderr
    assert "step 1" not in r.stdout


def test_write_failure_during_run_aborts_not_silent(tmp_path):
    """A file-size limit makes HDF5 writes fail mid-run (EFBIG): the run must end aborted, exit 1."""
    import resource

    def limit():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (3_000_000, 3_000_000))

    runs = tmp_path / "runs"
    r = subprocess.run(
        [sys.executable, "-m", "bench", "run", str(STARTUP), "--config", str(SIM_CONFIG), "--sim", "--runs-dir", str(runs)],
        cwd=ROOT, capture_output=True, text=True, timeout=120, preexec_fn=limit,
    )
    assert r.returncode == 1, r.stdout + r.stderr
    assert "COMPLETED" not in r.stdout
    assert "Traceback" not in r.stdout + r.stderr
    out = r.stdout + r.stderr
    assert "ABORTED" in out or "could not be finalised" in out
    path = _only_run_file(runs)
    s = read_run_summary(path, stale_after_s=0)
    assert s.status != "completed"


def _start_realtime(tmp_path: Path, seconds: int) -> tuple[subprocess.Popen, Path]:
    proc = write_procedure(
        tmp_path / "stationary.yaml",
        f"  - power: {{instrument: acs_board, on: true}}\n  - record: {{instrument: acs_board, duration: {seconds} s}}\n",
    )
    runs = tmp_path / "runs"
    p = subprocess.Popen(
        [sys.executable, "-m", "bench", "run", str(proc), "--config", str(SIM_CONFIG), "--sim", "--realtime", "--runs-dir", str(runs)],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    return p, runs


def _wait_for_rows(runs: Path, rows: int, timeout_s: float = 30.0) -> Path:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        files = list(runs.glob("*.h5")) if runs.exists() else []
        if files:
            try:
                s = read_run_summary(files[0])
                if s.streams and s.streams[0].rows >= rows:
                    return files[0]
            except Exception:  # noqa: BLE001 - file not yet in SWMR mode; keep polling
                time.sleep(0.05)
                continue
        time.sleep(0.1)
    raise AssertionError(f"no run file with {rows} rows in {runs} within {timeout_s} s")


def test_kill_9_during_realtime_run_leaves_readable_file(tmp_path):
    p, runs = _start_realtime(tmp_path, 60)
    try:
        path = _wait_for_rows(runs, 150)
        s = read_run_summary(path)  # readable while being written
        assert s.status == "running"
        time.sleep(0.7)
        p.send_signal(signal.SIGKILL)
        p.wait(timeout=10)
    finally:
        if p.poll() is None:
            p.kill()
    s = read_run_summary(path, stale_after_s=0)
    assert s.status not in ("completed", "running")
    assert s.streams[0].rows >= 150
    r = run_cli("inspect", str(path))
    status_line = next(line for line in r.stdout.splitlines() if line.startswith("status"))
    # just killed: the heartbeat is fresh, so inspect cannot yet tell a crash from a live writer
    assert r.returncode == 0 and ("crashed" in status_line or "running" in status_line), status_line


@pytest.mark.signals
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT, signal.SIGXFSZ],
                         ids=["SIGINT", "SIGTERM", "SIGHUP", "SIGQUIT", "SIGXFSZ"])
def test_signal_aborts_to_safe_state(tmp_path, sig):
    p, runs = _start_realtime(tmp_path, 60)
    try:
        path = _wait_for_rows(runs, 100)
        p.send_signal(sig)
        out, err = p.communicate(timeout=20)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 1, out + err
    assert "Traceback" not in out + err
    assert sig.name in out
    s = read_run_summary(path)
    assert s.status == "aborted" and sig.name in s.abort_reason
    kinds = [e.kind for e in s.events]
    assert "safe_state" in kinds and "abort" in kinds
    assert s.steps[-1].outcome == "aborted"
    # the stop-stream command went out and was acknowledged (0x92)
    assert any(e.kind == "reply" and e.data[2:3] == b"\x92" for e in s.events)


@pytest.mark.signals
def test_second_sigint_does_not_skip_safe_state(tmp_path):
    p, runs = _start_realtime(tmp_path, 60)
    try:
        path = _wait_for_rows(runs, 100)
        # an impatient operator: Ctrl-C again and again while the run stops and the process exits
        for _ in range(100):
            if p.poll() is not None:
                break
            p.send_signal(signal.SIGINT)
            time.sleep(0.002)
        out, err = p.communicate(timeout=20)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 1 and "Traceback" not in out + err
    assert "will not be skipped" in out
    s = read_run_summary(path)
    assert s.status == "aborted"
    assert [e.kind for e in s.events].count("safe_state") == 1


@pytest.mark.slow
def test_kill_9_soak_at_many_random_moments(tmp_path):
    """On demand (BENCH_SLOW=1): SIGKILL `bench run --sim --realtime` at 20 random moments of its
    life, from start-up to mid-recording; every file that exists must be readable with its data,
    or (killed before recording started) refused with a clear message, and never `completed`."""
    import random

    from bench.errors import InputError

    rnd = random.Random(20261123)
    for i in range(20):
        case = tmp_path / f"k{i}"
        case.mkdir()
        p, runs = _start_realtime(case, 30)
        time.sleep(rnd.uniform(0.0, 4.0))
        p.send_signal(signal.SIGKILL)
        p.wait(timeout=10)
        for path in runs.glob("*.h5") if runs.exists() else []:
            try:
                s = read_run_summary(path, stale_after_s=0)
            except InputError as exc:
                assert "open for writing outside SWMR mode" in str(exc), str(exc)
                continue
            assert s.status not in ("completed", "running")
            for st in s.streams:  # what is on disk is consistent: ordered, and not newer than the last flush
                data = read_stream(path, st.key)
                assert len(data["time"]) == st.rows
                assert np.all(np.diff(data["time"]) > 0)
                if st.rows:
                    assert data["time"][-1] <= s.heartbeat_run_time_s + 0.01
                    assert np.all(np.diff(data["counter"].astype(int)) % 65536 == 1)


def test_sim_run_of_instrument_without_simulator_is_bad_input(tmp_path):
    config = tmp_path / "hw.yaml"
    config.write_text("schema: bench-config/1\ninstruments:\n  acs_board:\n    driver: acs_board\n    port: /dev/ttyUSB0\n")
    r = run_cli("run", str(STARTUP), "--config", str(config), "--sim", "--runs-dir", str(tmp_path / "runs"))
    assert r.returncode == 2 and r.stderr.startswith(f"{config}:4:")
    assert "no 'sim' section" in r.stderr and not (tmp_path / "runs").exists()
