"""Run recorder: round trip, never overwriting, SIGKILL at random moments, live reading,
destination checks, write failures, damaged files."""

from __future__ import annotations

import io
import os
import random
import shutil
import subprocess
import sys
import tempfile
import textwrap
import threading
import time
from datetime import datetime, timezone
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rich.console import Console

from bench.errors import DestinationError, InputError, RecorderError
from bench.record import (
    FORMAT_VERSION,
    Column,
    RunRecorder,
    check_destination,
    read_run_summary,
    read_stream,
    render_summary,
    run_file_name,
)
from bench.record import reader as reader_mod
from bench.record import writer as writer_mod

ROOT = Path(__file__).resolve().parents[1]
T0 = datetime(2026, 11, 23, 1, 2, 3, tzinfo=timezone.utc)
PROC_TEXT = "schema: bench-procedure/1\nname: startup_profile\n# ünïcode ✓\nsteps: []\n"
CONFIG_TEXT = "lab: sim\ninstruments:\n  acs_board: {port: 'sim://acs'}\n"
ACS = [
    Column("counter", "1", "u2"),
    Column("gyro", "deg/s", "f8", (3,)),
    Column("temp", "degC", "f4"),
]


class FakeClock:
    """Wall clock (s) the test advances by hand."""

    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def make_recorder(runs: Path, **kw) -> RunRecorder:
    args = dict(
        procedure_name="startup_profile", procedure_text=PROC_TEXT, procedure_path="procedures/startup_profile.yaml",
        config_text=CONFIG_TEXT, config_path="configs/sim.yaml", mode="sim", operator="tester",
        software_version="9.9.9", started_utc=T0,
    )
    args.update(kw)
    return RunRecorder.create(runs, **args)


def acs_batch(t0: float, n: int, rate_hz: float, first_counter: int = 0) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    t = t0 + np.arange(n) / rate_hz
    return t, {
        "counter": (first_counter + np.arange(n)) % 65536,
        "gyro": np.column_stack([np.sin(t), np.cos(t), t]),
        "temp": np.full(n, 21.5, dtype=np.float32),
    }


# ---- round trip -------------------------------------------------------------------------------
def test_round_trip(tmp_path: Path) -> None:
    clock = FakeClock()
    rec = make_recorder(tmp_path, wall_clock=clock)
    assert rec.path == tmp_path / "20261123T010203Z_startup_profile.h5"
    rec.add_instrument("acs_board", {"vendor": "NPS", "model": "ACS-1", "serial": "0042", "firmware": "1.3", "transport": "serial", "port": "sim://acs"})
    acs = rec.add_stream("acs_board", ACS, rate_hz=100.0)
    daq = rec.add_stream("table", [Column("rate", "deg/s")], stream="encoder")
    assert (acs, daq) == ("acs_board", "table/encoder")
    rec.event("note", "procedure", "before start: set up", t_s=0.0, data=b"\x00\x01")
    rec.start()
    rec.event("run_start", "runner", "startup_profile: 2 steps, mode sim", t_s=0.0)
    rec.event("step_start", "record", "warm-up", t_s=0.0, step=0)
    counter = 0
    for i in range(20):  # 20 batches of 0.5 s at 100 Hz = 1000 rows, t = 0 .. 9.99 s
        t, cols = acs_batch(i * 0.5, 50, 100.0, counter)
        counter += 50
        rec.append(acs, t, **cols)
        clock.t += 0.5
        rec.tick(float(t[-1]))
    rec.event("command", "acs_board", "0x21", t_s=10.0, step=0, data=bytes([0xAA, 0x21, 0x00]))
    rec.event("step_end", "record", "done: 1000 rows in window 'warm-up'", t_s=10.0, step=0)
    rec.event("step_start", "bit", "built-in test", t_s=10.0, step=1)
    rec.append(daq, np.array([10.0, 10.5, 11.0]), rate=np.array([1.0, 2.0, 3.0]))
    rec.event("step_end", "bit", "failed: failed-subsystem mask 0x0004, expected 0x0000", t_s=11.0, step=1)
    rec.event("run_end", "runner", "completed", t_s=11.0)
    assert rec.rows_written(acs) == 1000 and rec.rows_written(daq) == 3
    rec.close("completed")
    rec.close("completed")  # idempotent

    s = read_run_summary(rec.path)
    assert s.status == "completed" and s.abort_reason == ""
    assert s.procedure_text == PROC_TEXT and s.config_text == CONFIG_TEXT
    a = s.attrs
    assert a["format_version"] == FORMAT_VERSION and a["software_version"] == "9.9.9"
    assert a["procedure_name"] == "startup_profile" and a["procedure_path"] == "procedures/startup_profile.yaml"
    assert a["config_path"] == "configs/sim.yaml" and a["operator"] == "tester" and a["mode"] == "sim"
    assert a["started_utc"] == "2026-11-23T01:02:03Z" and a["ended_utc"].endswith("Z") and a["host"]
    assert a["rows_total"] == 1003
    assert s.instruments["acs_board"]["serial"] == "0042"
    assert list(s.instruments["acs_board"]) == ["vendor", "model", "serial", "firmware", "transport", "port"]

    streams = {x.key: x for x in s.streams}
    sa = streams["acs_board"]
    assert sa.rows == 1000 and sa.t_start_s == 0.0 and sa.t_end_s == pytest.approx(9.99)
    assert sa.rate_hz == pytest.approx(100.0)
    assert sa.columns == {"counter": "1", "gyro": "deg/s", "temp": "degC"}
    assert sa.shapes == {"counter": (), "gyro": (3,), "temp": ()}
    sd = streams["table/encoder"]
    assert (sd.rows, sd.t_start_s, sd.t_end_s, sd.rate_hz) == (3, 10.0, 11.0, pytest.approx(2.0))

    data = read_stream(rec.path, "acs_board")
    t, cols = acs_batch(0.0, 1000, 100.0)
    np.testing.assert_allclose(data["time"], t)
    np.testing.assert_array_equal(data["counter"], np.arange(1000))
    assert data["counter"].dtype == np.uint16 and data["temp"].dtype == np.float32
    assert data["gyro"].shape == (1000, 3)
    np.testing.assert_allclose(data["gyro"], cols["gyro"])

    assert [(x.index, x.name, x.outcome, x.t_start_s, x.t_end_s) for x in s.steps] == [
        (0, "warm-up", "done", 0.0, 10.0),
        (1, "built-in test", "failed", 10.0, 11.0),
    ]
    assert s.steps[1].detail == "failed-subsystem mask 0x0004, expected 0x0000" and s.steps[1].type == "bit"
    kinds = [e.kind for e in s.events]
    assert kinds == ["note", "run_start", "step_start", "command", "step_end", "step_start", "step_end", "run_end"]
    assert s.events[0].message == "before start: set up" and s.events[0].data == b"\x00\x01"
    cmd = s.events[3]
    assert (cmd.source, cmd.step, cmd.message, cmd.data, cmd.t_s) == ("acs_board", 0, "0x21", b"\xaa\x21\x00", 10.0)
    assert s.event_counts["step_end"] == 2

    with h5py.File(rec.path, "r") as f:  # the layout docs/run-file.md describes
        assert f["streams/acs_board/gyro"].attrs["units"] == "deg/s"
        assert f["streams/acs_board/time"].attrs["units"] == "s"
        assert f["streams/acs_board/gyro"].maxshape == (None, 3)
        assert f["streams/acs_board/gyro"].compression is None
        assert f["events"].dtype.names == ("t_s", "wall_unix", "kind", "source", "step", "msg_off", "msg_len", "data_off", "data_len")
        assert f["heartbeat"].shape == (2,) and f["heartbeat"][1] == pytest.approx(11.0)
        assert f["procedure/text"].dtype.kind == "S"  # fixed length, not variable length

    console = Console(record=True, width=200)
    render_summary(s, console)
    out = console.export_text()
    for text in ("startup_profile", "completed", "acs_board", "100 Hz", "gyro[3] (deg/s)", "built-in test", "failed",
                 "acs_board: 1 command, 0 replies, last at 0:00:10", "step_end 2"):
        assert text in out, text
    assert "aa 21 00" not in out  # instrument traffic is summarised, not listed ...
    console = Console(record=True, width=200)
    render_summary(s, console, traffic=True)
    out = console.export_text()
    assert "0x21" in out and "aa 21 00" in out  # ... unless asked for


def test_tick_flushes_once_per_interval_of_wall_time(tmp_path: Path) -> None:
    clock = FakeClock()
    rec = make_recorder(tmp_path, wall_clock=clock, flush_interval_s=1.0)
    key = rec.add_stream("daq", [Column("v", "V")])
    rec.start()
    for i in range(25):  # 0.1 s of wall time per batch
        rec.append(key, np.array([i * 0.1]), v=np.array([float(i)]))
        clock.t += 0.1
        rec.tick(i * 0.1)
        # data is on disk at the first tick at least 1 s after the previous flush
        assert rec.rows_on_disk(key) == (10 if i >= 9 else 0) + (10 if i >= 19 else 0)
    assert rec.rows_written(key) == 25
    rec.close("completed")
    assert read_stream(rec.path, key)["v"].shape == (25,)


def test_append_and_setup_validation(tmp_path: Path) -> None:
    rec = make_recorder(tmp_path)
    key = rec.add_stream("acs_board", ACS)
    with pytest.raises(ValueError, match="already added"):
        rec.add_stream("acs_board", ACS)
    with pytest.raises(ValueError, match="reserved"):
        rec.add_stream("x", [Column("time", "s")])
    rec.start()
    t, cols = acs_batch(0.0, 10, 100.0)
    with pytest.raises(ValueError, match="missing column.*temp"):
        rec.append(key, t, counter=cols["counter"], gyro=cols["gyro"])
    with pytest.raises(ValueError, match="unknown column.*pressure"):
        rec.append(key, t, **cols, pressure=t)
    with pytest.raises(ValueError, match=r"'gyro' has shape \(10, 2\), expected \(10, 3\)"):
        rec.append(key, t, **{**cols, "gyro": np.zeros((10, 2))})
    with pytest.raises(ValueError, match="floats.*integer column"):
        rec.append(key, t, **{**cols, "counter": np.zeros(10)})
    with pytest.raises(ValueError, match="outside the range of uint16"):
        rec.append(key, t, **{**cols, "counter": np.arange(10) - 1})
    with pytest.raises(ValueError, match="unknown stream"):
        rec.append("nope", t, **cols)
    with pytest.raises(ValueError, match="only allowed before start"):
        rec.add_stream("late", [Column("v", "V")])
    with pytest.raises(ValueError, match="only allowed before start"):
        rec.add_instrument("late", {})
    with pytest.raises(ValueError, match="1 to 16"):
        rec.event("a_kind_that_is_far_too_long", t_s=0.0)
    rec.append(key, t, **{**cols, "counter": np.arange(10, dtype=np.int64)})  # fits: accepted
    rec.event("note", "s" * 40, "long source is cut to 32 bytes", t_s=0.0)
    rec.close("completed")
    assert rec.rows_written(key) == 10
    assert read_run_summary(rec.path).events[0].source == "s" * 32
    with pytest.raises(ValueError, match="closed"):
        rec.append(key, t, **cols)


def test_run_file_name() -> None:
    assert run_file_name(T0, "startup_profile") == "20261123T010203Z_startup_profile.h5"
    assert run_file_name(T0, "../etc/pass wd ✓") == "20261123T010203Z_etc_pass_wd.h5"
    assert run_file_name(T0, "///") == "20261123T010203Z_run.h5"
    naive = datetime(2026, 11, 23, 1, 2, 3)
    assert run_file_name(naive, "a") == "20261123T010203Z_a.h5"


def test_never_overwrites(tmp_path: Path) -> None:
    first = make_recorder(tmp_path)
    second = make_recorder(tmp_path)
    third = make_recorder(tmp_path)
    assert first.path.name == "20261123T010203Z_startup_profile.h5"
    assert second.path.name == "20261123T010203Z_startup_profile_1.h5"
    assert third.path.name == "20261123T010203Z_startup_profile_2.h5"
    for r in (first, second, third):
        r.start()
        r.close("completed")
    assert len(list(tmp_path.glob("*.h5"))) == 3
    assert all(read_run_summary(p).status == "completed" for p in tmp_path.glob("*.h5"))


def test_closed_before_start_and_context_manager(tmp_path: Path) -> None:
    rec = make_recorder(tmp_path)
    rec.event("error", "acs_board", "port /dev/ttyUSB0 not found", t_s=0.0)
    rec.close("aborted", "instruments could not be opened")
    s = read_run_summary(rec.path)
    assert (s.status, s.abort_reason) == ("aborted", "instruments could not be opened")
    assert [e.message for e in s.events] == ["port /dev/ttyUSB0 not found"]

    with pytest.raises(RuntimeError, match="boom"):
        with make_recorder(tmp_path) as rec2:
            rec2.start()
            rec2.event("step_start", "wait", "soak", t_s=1.0, step=0)
            raise RuntimeError("boom")
    s2 = read_run_summary(rec2.path)
    assert (s2.status, s2.abort_reason) == ("aborted", "boom")
    assert [(x.name, x.outcome, x.t_end_s) for x in s2.steps] == [("soak", "interrupted", None)]


# ---- subprocess writers -----------------------------------------------------------------------
WRITER = textwrap.dedent(
    """
    import os, sys, time
    import numpy as np
    from pathlib import Path
    from bench.record import Column, RunRecorder
    from bench.errors import RecorderError

    runs, mode = Path(sys.argv[1]), sys.argv[2]
    if mode.startswith("fsize"):
        import resource, signal
        limit = int(sys.argv[3])
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
        if mode == "fsize_unchecked":  # let HDF5 itself run into EFBIG
            RunRecorder._check_space = lambda self: None
    cols = [Column(f"ch{i:02d}", "V") for i in range(16)] + [Column("vec", "g", "f8", (3,))]
    print("ready", flush=True)
    rec = RunRecorder.create(runs, procedure_name="kill test", procedure_text="p", procedure_path="p.yaml",
                             config_text="c", config_path="c.yaml", mode="sim", software_version="test")
    print("created", rec.path, flush=True)
    keys = []
    for i in range(6):  # identifying instruments takes a while on a real bench
        rec.add_instrument(f"inst{i}", {"vendor": "test", "serial": str(i)})
        keys.append(rec.add_stream(f"inst{i}", cols))
        time.sleep(0.004)
    key = keys[0]

    def batch(i, n=100):
        t = i * 0.1 + np.arange(n) / 1000.0
        return t, {**{c.name: np.full(n, float(i)) for c in cols[:16]}, "vec": np.ones((n, 3))}

    def wait_for(word):
        line = sys.stdin.readline().strip()
        assert line == word, line

    if mode == "paused":
        print("setup done", flush=True)
        wait_for("start")
    rec.start()
    print("started", flush=True)
    rec.event("step_start", "record", "fast stream", t_s=0.0, step=0)
    i = 0
    try:
        while True:
            t, data = batch(i)
            rec.append(key, t, **data)
            i += 1
            if i % 5 == 0:
                rec.event("note", "writer", f"batch {i}", t_s=float(t[-1]), step=0)
                rec.flush()
                print("flushed", rec.rows_on_disk(key), flush=True)
                if mode == "paused":
                    cmd = sys.stdin.readline().strip()
                    if cmd == "close":
                        rec.event("step_end", "record", "done", t_s=float(t[-1]), step=0)
                        rec.close("completed")
                        print("closed", flush=True)
                        break
            else:
                time.sleep(0.002)
            if i > 20000:
                break
    except RecorderError as exc:
        print("error", type(exc).__name__, exc, flush=True)
        try:
            rec.event("abort", "runner", f"recorder: {exc}", t_s=i * 0.1)
        except RecorderError as exc2:
            print("event error", type(exc2).__name__, exc2, flush=True)
        try:
            rec.close("aborted", f"recorder: {exc}")
            print("close ok", flush=True)
        except RecorderError as exc2:
            print("close error", type(exc2).__name__, exc2, flush=True)
    """
)


def _writer(tmp_path: Path) -> Path:
    script = tmp_path / "writer.py"
    script.write_text(WRITER)
    return script


def _spawn(script: Path, runs: Path, mode: str, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, str(script), str(runs), mode, *extra], cwd=ROOT, stdin=subprocess.PIPE,
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, bufsize=1,
    )


class LineReader:
    """Collects a subprocess' stdout lines in a thread."""

    def __init__(self, proc: subprocess.Popen) -> None:
        self.lines: list[str] = []
        self.cond = threading.Condition()
        self.thread = threading.Thread(target=self._run, args=(proc,), daemon=True)
        self.thread.start()

    def _run(self, proc: subprocess.Popen) -> None:
        for line in proc.stdout:
            with self.cond:
                self.lines.append(line.rstrip("\n"))
                self.cond.notify_all()

    def wait_for(self, prefix: str, timeout: float = 30.0, after: int = 0) -> str:
        deadline = time.monotonic() + timeout
        with self.cond:
            while True:
                for line in self.lines[after:]:
                    if line.startswith(prefix):
                        return line
                left = deadline - time.monotonic()
                if left <= 0:
                    raise AssertionError(f"no {prefix!r} line from the writer; got {self.lines[-5:]}")
                self.cond.wait(left)

    def last_flushed(self) -> int:
        rows = [int(line.split()[1]) for line in self.lines if line.startswith("flushed ")]
        return rows[-1] if rows else 0


def test_sigkill_at_random_moments(tmp_path: Path) -> None:
    script = _writer(tmp_path)
    rnd = random.Random(20261123)
    delays = [0.0, 0.003, 0.008] + [rnd.uniform(0.01, 0.06) for _ in range(3)] + [rnd.uniform(0.06, 0.5) for _ in range(8)]
    outcomes = []
    for n, delay in enumerate(delays):
        runs = tmp_path / f"runs{n}"
        proc = _spawn(script, runs, "kill")
        lines = LineReader(proc)
        lines.wait_for("ready")
        time.sleep(delay)
        proc.kill()  # SIGKILL
        proc.wait(10)
        lines.thread.join(10)
        started = any(line == "started" for line in lines.lines)
        flushed = lines.last_flushed()
        files = list(runs.glob("*.h5")) if runs.exists() else []
        if not files:
            assert not started, "the writer reported a started run but left no file"
            outcomes.append("no file")
            continue
        assert len(files) == 1
        path = files[0]
        if started:
            with h5py.File(path, "r", swmr=True) as f:  # plain h5py opens it
                assert f.attrs["status"] == "running"
            s = read_run_summary(path, stale_after_s=0.0)
            assert s.status == "crashed" and "no heartbeat since" in s.status_detail
            assert read_run_summary(path).status == "running"  # heartbeat younger than 10 s
            rows = {x.key: x.rows for x in s.streams}["inst0"]
            assert rows >= flushed
            assert read_stream(path, "inst0")["ch00"].shape == (rows,)
            if s.steps:
                assert s.steps[0].outcome == "interrupted"
            outcomes.append(f"crashed with {rows} rows (>= {flushed} reported flushed)")
        else:
            try:
                s = read_run_summary(path, stale_after_s=0.0)
                assert s.status == "crashed"
                outcomes.append("killed before start: readable")
            except InputError as exc:
                msg = str(exc)
                assert msg.startswith(f"{path}: not a readable bench run file: ")
                assert any(w in msg for w in ("open for writing outside SWMR mode", "truncated", "empty", "no HDF5 signature")), msg
                outcomes.append("killed before start: InputError")
    print("\n".join(outcomes))
    assert sum(o.startswith("crashed") for o in outcomes) >= 5, outcomes
    assert any(o.startswith("crashed") and not o.startswith("crashed with 0 ") for o in outcomes), outcomes


def test_read_while_being_written(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(reader_mod, "LOCK_WAIT_S", 0.2)
    script = _writer(tmp_path)
    runs = tmp_path / "runs"
    proc = _spawn(script, runs, "paused")
    lines = LineReader(proc)
    try:
        path = Path(lines.wait_for("created").split(" ", 1)[1])
        lines.wait_for("setup done")
        # set up under a hidden name (HDF5 refuses readers then): the name holds a readable placeholder (issue 31, D5)
        s = read_run_summary(path)
        assert s.status == "running" and not s.streams and not s.events
        proc.stdin.write("start\n")
        proc.stdin.flush()
        rows = int(lines.wait_for("flushed").split()[1])
        s = read_run_summary(path)
        assert s.status == "running" and "being written" in s.status_detail
        assert {x.key: x.rows for x in s.streams}["inst0"] == rows == 500
        assert [(x.name, x.outcome) for x in s.steps] == [("fast stream", "running")]
        assert read_stream(path, "inst0")["vec"].shape == (500, 3)
        n = len(lines.lines)
        proc.stdin.write("more\n")
        proc.stdin.flush()
        assert int(lines.wait_for("flushed", after=n).split()[1]) == 1000
        assert {x.key: x.rows for x in read_run_summary(path).streams}["inst0"] == 1000
        proc.stdin.write("close\n")
        proc.stdin.flush()
        lines.wait_for("closed")
        assert proc.wait(10) == 0
        s = read_run_summary(path)
        assert s.status == "completed" and s.steps[0].outcome == "done"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)


# ---- destination and write failures ---------------------------------------------------------------
def test_destination_refused(tmp_path: Path) -> None:
    check_destination(tmp_path / "new" / "runs", 1000)  # creates it
    assert (tmp_path / "new" / "runs").is_dir()
    assert list((tmp_path / "new" / "runs").iterdir()) == []  # the probe file is gone

    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    with pytest.raises(DestinationError, match=f"runs directory {blocker}/runs cannot be created"):
        check_destination(blocker / "runs", 1000)
    with pytest.raises(DestinationError, match="cannot be created"):
        make_recorder(blocker / "runs")
    with pytest.raises(DestinationError, match="is not a directory|cannot be created"):
        check_destination(blocker, 1000)

    with pytest.raises(DestinationError, match=rf"not enough free space in runs directory {tmp_path}: .* MB free, the run needs"):
        check_destination(tmp_path, 10**18)

    if os.geteuid() != 0:  # root is not stopped by permission bits
        locked = tmp_path / "locked"
        locked.mkdir()
        locked.chmod(0o555)
        try:
            with pytest.raises(DestinationError, match=f"runs directory {locked} is not writable: Permission denied"):
                check_destination(locked, 1000)
        finally:
            locked.chmod(0o755)


def test_file_size_limit_stops_recording_cleanly(tmp_path: Path) -> None:
    """Before the disk (here RLIMIT_FSIZE) is full, flush refuses to write: the file is closed as aborted."""
    runs = tmp_path / "runs"
    proc = subprocess.run(
        [sys.executable, str(_writer(tmp_path)), str(runs), "fsize", str(4_000_000)],
        cwd=ROOT, capture_output=True, text=True, timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    assert "error RecorderError" in proc.stdout and "close ok" in proc.stdout, proc.stdout
    err = next(line for line in proc.stdout.splitlines() if line.startswith("error "))
    path = next(runs.glob("*.h5"))
    assert f"writing {path} failed: file size limit (ulimit -f) of 4.0 MB reached" in err
    s = read_run_summary(path)
    assert s.status == "aborted" and "file size limit" in s.abort_reason
    assert s.events[-1].kind == "abort" and "file size limit" in s.events[-1].message  # written at close
    flushed = [int(line.split()[1]) for line in proc.stdout.splitlines() if line.startswith("flushed")]
    rows = {x.key: x.rows for x in s.streams}["inst0"]
    # the rows accepted before the refused flush fit in the reserve the refusal kept: none lost
    with h5py.File(path, "r") as f:
        assert rows == int(f["streams/inst0"].attrs["rows_appended"]) > flushed[-1]


def test_failed_hdf5_write_is_reported_not_silent(tmp_path: Path) -> None:
    """HDF5 itself hits EFBIG: RecorderError with the OS reason, no crash, data of the last flush kept."""
    runs = tmp_path / "runs"
    proc = subprocess.run(
        [sys.executable, str(_writer(tmp_path)), str(runs), "fsize_unchecked", str(3_000_000)],
        cwd=ROOT, capture_output=True, text=True, timeout=60,
    )
    assert proc.returncode == 0, (proc.returncode, proc.stderr[-2000:])  # HDF5 would segfault on close
    path = next(runs.glob("*.h5"))
    err = next(line for line in proc.stdout.splitlines() if line.startswith("error "))
    assert err.startswith(f"error RecorderError writing {path} failed: File too large [errno 27]"), err
    assert "event error RecorderError" in proc.stdout  # nothing more is accepted after a failed write
    close = next(line for line in proc.stdout.splitlines() if line.startswith("close "))
    assert close.startswith("close error RecorderError") and "cannot be finalised" in close
    flushed = [int(line.split()[1]) for line in proc.stdout.splitlines() if line.startswith("flushed")]
    with h5py.File(path, "r", swmr=True) as f:  # opens; the superblock may claim more bytes than were written
        assert f["streams/inst0/ch00"].shape[0] >= flushed[-1] > 0
    s = read_run_summary(path, stale_after_s=0.0)
    assert s.status == "crashed"
    assert {x.key: x.rows for x in s.streams}["inst0"] >= flushed[-1]
    if path.stat().st_size >= 3_000_000:  # the failed write left the file shorter than HDF5 expects
        assert s.warnings and "truncated" in s.warnings[0]


def test_disk_nearly_full_refuses_flush_keeps_events(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    rec = make_recorder(tmp_path)
    key = rec.add_stream("daq", [Column("v", "V")])
    rec.start()
    rec.append(key, np.arange(10.0), v=np.ones(10))
    rec.flush()
    rec.append(key, np.arange(10.0, 20.0), v=np.ones(10))  # accepted: room for them and the reserve
    real = shutil.disk_usage
    free = rec.space_needed() - 1  # the disk filled up meanwhile: just short of next write + reserve
    monkeypatch.setattr(writer_mod.shutil, "disk_usage", lambda p: real(p)._replace(free=free))
    with pytest.raises(RecorderError, match=f"writing {rec.path} failed: disk nearly full: {free / 1e6:.1f} MB free"):
        rec.flush()
    with pytest.raises(RecorderError, match="failed earlier: disk nearly full"):
        rec.append(key, np.arange(20.0, 30.0), v=np.ones(10))
    rec.event("abort", "runner", "recorder: disk nearly full", t_s=20.0)  # still accepted: the abort story
    with pytest.raises(RecorderError, match="closed with status 'aborted'"):
        rec.close("completed")
    rec.close("aborted")  # closed: no-op
    s = read_run_summary(tmp_path / rec.path.name)
    assert s.status == "aborted" and s.abort_reason.startswith("writing the run file failed: disk nearly full")
    # the 10 rows accepted before the refusal fit in the reserve the refusal kept: none lost
    assert [x.rows for x in s.streams] == [20] and rec.rows_written(key) == 20
    assert s.events[-1].message == "recorder: disk nearly full"
    with h5py.File(rec.path, "r") as f:
        assert (f["streams/daq"].attrs["rows"], f["streams/daq"].attrs["rows_appended"]) == (20, 20)
        assert list(f["streams/daq/time"][:]) == list(np.arange(20.0))


def test_disk_filling_refuses_new_rows_at_append(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Rows are accepted only while they and the reserve fit: a refused append is not counted. A
    free-space reading stands for appends that need no new chunk for SPACE_RECHECK_S of wall time."""
    now = [0.0]
    rec = make_recorder(tmp_path, wall_clock=lambda: now[0])
    key = rec.add_stream("daq", [Column("v", "V")])
    rec.start()
    asked = []
    real = shutil.disk_usage
    free = [10**12]
    monkeypatch.setattr(writer_mod.shutil, "disk_usage", lambda p: asked.append(p) or real(p)._replace(free=free[0]))
    rec.append(key, np.arange(5.0), v=np.ones(5))
    assert len(asked) == 1
    free[0] = 600_000  # the disk filled up meanwhile
    now[0] += writer_mod.SPACE_RECHECK_S / 2
    rec.append(key, np.arange(5.0, 6.0), v=np.ones(1))  # same chunk, reading still current: not asked again
    assert len(asked) == 1 and rec.rows_written(key) == 6
    now[0] += writer_mod.SPACE_RECHECK_S / 2
    with pytest.raises(RecorderError, match="disk nearly full: 0.6 MB free"):
        rec.append(key, np.arange(6.0, 10.0), v=np.ones(4))
    assert len(asked) == 2 and rec.rows_written(key) == 6
    rec.close("aborted", "disk nearly full")
    with h5py.File(rec.path, "r") as f:
        assert (f["streams/daq"].attrs["rows"], f["streams/daq"].attrs["rows_appended"]) == (6, 6)


def test_free_space_asked_again_when_a_new_chunk_is_needed(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Within SPACE_RECHECK_S, an append whose rows need more chunks than the last reading covered
    asks the disk again (and a flush always does)."""
    now = [0.0]
    rec = make_recorder(tmp_path, wall_clock=lambda: now[0])
    key = rec.add_stream("daq", [Column("v", "V")])
    rec.start()
    real = shutil.disk_usage
    free = [10**12]
    monkeypatch.setattr(writer_mod.shutil, "disk_usage", lambda p: real(p)._replace(free=free[0]))
    rec.append(key, np.arange(5.0), v=np.ones(5))
    free[0] = rec.space_needed()  # exactly what the reading covered
    rows = max(rec._stream(key).chunk_bytes.values()) // 8 + 1  # more than a chunk of float64: a new chunk
    with pytest.raises(RecorderError, match="disk nearly full"):
        rec.append(key, 5.0 + np.arange(rows), v=np.ones(rows))
    assert rec.rows_written(key) == 5


# ---- damaged files ---------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def good_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    runs = tmp_path_factory.mktemp("good")
    rec = make_recorder(runs)
    rec.add_instrument("acs_board", {"vendor": "NPS"})
    key = rec.add_stream("acs_board", ACS)
    rec.start()
    for i in range(4):
        t, cols = acs_batch(i, 100, 100.0, i * 100)
        rec.append(key, t, **cols)
        rec.event("step_start", "record", f"step {i}", t_s=float(i), step=i, data=b"\x01\x02")
        rec.event("step_end", "record", "done", t_s=float(i) + 0.99, step=i)
        rec.flush()
    rec.close("completed")
    return rec.path


def test_damaged_and_foreign_files(tmp_path: Path, good_file: Path) -> None:
    data = good_file.read_bytes()
    cases = {
        "missing.h5": None,
        "empty.h5": b"",
        "garbage.h5": b"this is not HDF5 at all\n" * 100,
        "half.h5": data[: len(data) // 2],
        "head.h5": data[:100],
    }
    for name, content in cases.items():
        p = tmp_path / name
        if content is not None:
            p.write_bytes(content)
        with pytest.raises(InputError, match=rf"^{p}: not a readable bench run file: "):
            read_run_summary(p)
    with pytest.raises(InputError, match="no such file"):
        read_run_summary(tmp_path / "missing.h5")
    with pytest.raises(InputError, match="not an HDF5 file"):
        read_run_summary(tmp_path / "garbage.h5")
    with pytest.raises(InputError, match="truncated"):
        read_run_summary(tmp_path / "half.h5")

    foreign = tmp_path / "foreign.h5"
    with h5py.File(foreign, "w") as f:
        f["x"] = np.arange(3)
    with pytest.raises(InputError, match="no format_version attribute"):
        read_run_summary(foreign)

    newer = tmp_path / "newer.h5"
    shutil.copy(good_file, newer)
    with h5py.File(newer, "r+") as f:
        f.attrs["format_version"] = FORMAT_VERSION + 1
    with pytest.raises(InputError, match=f"format_version {FORMAT_VERSION + 1} is newer than this bench reads"):
        read_run_summary(newer)
    with pytest.raises(InputError, match="no stream 'nope'"):
        read_stream(good_file, "nope")


@pytest.fixture(scope="module")
def crashed_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy of a file taken while its writer was in SWMR mode: what a SIGKILL leaves."""
    runs = tmp_path_factory.mktemp("crashed")
    rec = make_recorder(runs)
    key = rec.add_stream("acs_board", ACS)
    rec.start()
    for i in range(3):
        t, cols = acs_batch(i, 100, 100.0, i * 100)
        rec.append(key, t, **cols)
        rec.event("step_start", "record", f"step {i}", t_s=float(i), step=i)
        rec.flush()
    snapshot = runs / "snapshot.h5"
    shutil.copy(rec.path, snapshot)
    rec.close("completed")
    s = read_run_summary(snapshot, stale_after_s=0.0)
    assert s.status == "crashed" and s.streams[0].rows == 300
    assert [x.outcome for x in s.steps] == ["interrupted"] * 3
    return snapshot


_EDITS = st.lists(st.tuples(st.floats(0.0, 1.0, exclude_max=True), st.integers(0, 255)), min_size=1, max_size=12)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(_EDITS)
def test_random_corruption_only_raises_input_error(good_file: Path, edits: list[tuple[float, int]]) -> None:
    _check_corrupted_copy(good_file, edits)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(_EDITS)
def test_random_corruption_of_crashed_file_only_raises_input_error(crashed_file: Path, edits: list[tuple[float, int]]) -> None:
    """Same through the SWMR-reader path (bounded metadata read retries)."""
    _check_corrupted_copy(crashed_file, edits)


def _check_corrupted_copy(source: Path, edits: list[tuple[float, int]]) -> None:
    data = bytearray(source.read_bytes())
    for where, value in edits:
        data[int(where * len(data))] = value
    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / "corrupt.h5"
        p.write_bytes(bytes(data))
        try:
            s = read_run_summary(p)
        except InputError as exc:
            assert str(exc).startswith(str(p))
            return
        render_summary(s, Console(file=io.StringIO(), width=120))
        for x in s.streams:
            try:
                read_stream(p, x.key)
            except InputError:
                pass


def test_close_waits_for_a_reader_holding_the_file(tmp_path: Path) -> None:
    """`bench watch` reading at the moment a run ends must not make the run fail to finalise."""
    rec = make_recorder(tmp_path)
    acs = rec.add_stream("acs_board", ACS, rate_hz=100.0)
    rec.start()
    t, cols = acs_batch(0.0, 100, 100.0)
    rec.append(acs, t, **cols)
    rec.flush()
    reader = h5py.File(rec.path, "r", libver="latest", swmr=True)  # holds HDF5's shared file lock
    releaser = threading.Timer(0.3, reader.close)
    releaser.start()
    t0 = time.monotonic()
    rec.close("completed")
    releaser.join()
    assert time.monotonic() - t0 >= 0.25  # it really had to wait for the reader
    assert read_run_summary(rec.path).status == "completed"


@pytest.mark.parametrize("session", sorted(p.name for p in (Path(__file__).parent / "sessions").glob("*.h5")))
def test_a_summary_of_some_event_kinds_reads_the_same_events_without_the_traffic(session: str) -> None:
    """The catalogue and the analyses ask for a few kinds: their events are decoded from the blob
    piece by piece (the traffic, most of a long run's file, is not read) and equal the full read's."""
    from bench.record import layout
    from bench.record.reader import read_run_summary

    path = Path(__file__).parent / "sessions" / session
    kinds = (*layout.STEP_EVENT_KINDS, layout.EVENT_CHECK, "procedure", "operator")
    full = [e for e in read_run_summary(path).events if e.kind in kinds]
    some = read_run_summary(path, event_kinds=kinds).events
    assert some == full and len(some) >= 4


_TORN_WRITER = r"""
import os, sys
import numpy as np
from pathlib import Path
from bench.record import Column, RunRecorder
rec = RunRecorder.create(Path(sys.argv[1]), procedure_name="torn", procedure_text="p", procedure_path="p.yaml",
                         config_text="c", config_path="c.yaml", mode="sim", software_version="test")
key = rec.add_stream("inst", [Column("v", "V")])
rec.start()
n = int(sys.argv[2])
rec.append(key, np.arange(n) / 100.0, v=np.arange(n, dtype=float))
rec.flush()
print(rec.path, flush=True)
if sys.argv[3] == "close":
    rec.close("completed", "")
os._exit(0)  # "kill -9": nothing else is written
"""


@pytest.mark.parametrize("ending", ["killed", "close"])
def test_a_torn_last_chunk_is_read_in_a_killed_file_and_excluded_in_a_finalised_one(tmp_path: Path, ending: str) -> None:
    """A writer killed while rewriting a stream's last (partial) chunk leaves its checksum wrong; the
    rows it had flushed are still there. Readers of a file not finalised read that chunk past its
    checksum; in a finalised file the same damage is left out; `inspect --verify` reports both."""
    import subprocess
    import sys

    import h5py

    from bench.record.reader import read_stream_checked

    n = 300  # rows: less than one chunk, so the only chunk is the last one
    out = subprocess.run([sys.executable, "-c", _TORN_WRITER, str(tmp_path), str(n), ending], capture_output=True, text=True,
                         timeout=60, cwd=Path(__file__).resolve().parents[1])
    path = Path(out.stdout.strip().splitlines()[-1])
    with h5py.File(path, "r", swmr=True) as f:
        ds = f["/streams/inst"]["v"]
        info = ds.id.get_chunk_info_by_coord((0,))
        chunk_rows = ds.chunks[0]
    assert chunk_rows > n
    with open(path, "r+b") as fh:  # a byte past the flushed rows changes: the torn rewrite
        fh.seek(info.byte_offset + (n + 5) * 8)
        b = fh.read(1)
        fh.seek(info.byte_offset + (n + 5) * 8)
        fh.write(bytes([b[0] ^ 0x40]))
    got = read_stream_checked(path, "inst")
    if ending == "killed":
        assert not got.excluded and np.array_equal(got.data["v"], np.arange(n, dtype=float))
    else:
        assert got.excluded and got.excluded[0].row_start == 0 and got.data["v"].size == 0
    verify = subprocess.run([sys.executable, "-m", "bench", "inspect", "--verify", str(path)], capture_output=True, text=True, timeout=60)
    assert verify.returncode == 1 and "FAILED" in verify.stdout, verify.stdout + verify.stderr


def test_append_row_stores_what_append_stores(tmp_path: Path) -> None:
    """One row at a time (a polled reading) gives the same datasets as one-row arrays, interleaved
    with batches in the order given; a value that is not a number, or a missing or unknown column,
    is refused with the stream and column named and nothing counted."""
    recs = []
    for how in ("rows", "arrays"):
        rec = make_recorder(tmp_path / how)
        key = rec.add_stream("chamber", [Column("air_c", "degC"), Column("p", "Torr")], "monitor")
        rec.start()
        for i in range(5):
            vals = {"air_c": 20.0 + i, "p": np.float32(1e-3 * i) if i % 2 else i}  # numpy and int values too
            if how == "rows":
                rec.append_row(key, float(i), vals)
            else:
                rec.append(key, np.array([float(i)]), **{k: np.array([v], dtype=float) for k, v in vals.items()})
            if i == 2:
                rec.flush()
        rec.append(key, np.array([5.0, 6.0]), air_c=np.array([1.0, 2.0]), p=np.array([3.0, 4.0]))
        if how == "rows":
            rec.append_row(key, 7.0, {"air_c": 9.0, "p": 8.0})
            for bad, match in (({"air_c": "21", "p": 1.0}, "column 'air_c' has a value of type str"),
                               ({"air_c": 1.0}, "missing column.*p"),
                               ({"air_c": 1.0, "p": 2.0, "x": 3.0}, "unknown column.*x")):
                with pytest.raises(ValueError, match=match):
                    rec.append_row(key, 8.0, bad)
        else:
            rec.append(key, np.array([7.0]), air_c=np.array([9.0]), p=np.array([8.0]))
        assert rec.rows_written(key) == 8
        rec.close("completed")
        recs.append(rec.path)
    with h5py.File(recs[0], "r") as a, h5py.File(recs[1], "r") as b:
        for name in ("time", "air_c", "p"):
            x, y = a[f"streams/chamber/monitor/{name}"], b[f"streams/chamber/monitor/{name}"]
            assert x.dtype == y.dtype and list(x[:]) == list(y[:]) and x.shape == (8,)


def test_read_traffic_is_the_summary_traffic_column_wise(tmp_path: Path) -> None:
    """read_traffic gives the command and reply events of read_run_summary, in order, field for
    field (kinds asked for only); a summary without traffic keeps every other event."""
    from bench.record.reader import read_traffic

    rec = make_recorder(tmp_path)
    rec.start()
    rng = np.random.default_rng(7)
    for i in range(3000):  # more than one event chunk and one blob chunk
        kind = ("command", "reply", "step_start", "reply")[i % 4]
        rec.event(kind, ("tvac", "rate_table", "ünï")[i % 3], f"read {i}" if i % 5 else "", t_s=i / 10, step=i % 7 - 1,
                  data=rng.bytes(int(rng.integers(0, 40))))
        if i % 900 == 0:
            rec.flush()
    rec.close("completed")
    events = read_run_summary(rec.path).events
    for kinds in (("command", "reply"), ("command",)):
        tr = read_traffic(rec.path, kinds)
        want = [e for e in events if e.kind in kinds]
        assert len(tr) == len(want) > 700
        assert (tr.t_s, tr.kind, tr.source, tr.step, tr.message, tr.data) == tuple(
            [getattr(e, f) for e in want] for f in ("t_s", "kind", "source", "step", "message", "data"))
    rest = read_run_summary(rec.path, traffic=False).events
    assert rest == [e for e in events if e.kind not in ("command", "reply")] and len(rest) == 750


def test_stream_chunk_cache_holds_two_chunks(tmp_path: Path) -> None:
    """Each stream dataset caches at most two of its chunks while written: a slow stream's finished
    chunks are not kept (the file default, 1 MiB a dataset, made memory grow with run length)."""
    rec = make_recorder(tmp_path)
    key = rec.add_stream("chamber", [Column("air_c", "degC")], "monitor", rate_hz=1.0)
    board = rec.add_stream("acs_board", ACS, rate_hz=100.0)
    rec.start()
    for k in (key, board):
        for name, ds in rec._stream(k).datasets.items():
            nbytes = ds.id.get_access_plist().get_chunk_cache()[1]
            assert nbytes == 2 * rec._stream(k).chunk_bytes[name] <= 2 * 1024 * 1024, (k, name, nbytes)
    rec.close("completed")
