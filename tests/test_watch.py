"""bench watch: live view of a run file while the recorder writes it (SWMR), in and across processes."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
from rich.console import Console

from bench.errors import EXIT_OK, InputError
from bench.record import Column, RunRecorder
from bench.runner.ingest import ACS_COLUMNS
from bench.watch import SPARK_CHARS, StepTracker, snapshot, sparkline, watch

ROOT = Path(__file__).resolve().parents[1]
TVAC_COLUMNS = [Column("air_temp", "degC"), Column("mount_temp", "degC"), Column("pressure", "Torr")]
RATE_HZ = 100.0


def _create(runs: Path, name: str = "watch_test") -> tuple[RunRecorder, str, str]:
    """A recorder set up the way the runner does it: instruments, board stream, monitor stream, start."""
    rec = RunRecorder.create(
        runs, procedure_name=name, procedure_text="schema: bench-procedure/1\n", procedure_path="p.yaml",
        config_text="name: test\n", config_path="c.yaml", mode="sim", software_version="test",
    )
    rec.add_instrument("acs_board", {"vendor": "test", "serial": "1"})
    rec.add_instrument("tvac", {"vendor": "test", "serial": "2"})
    board = rec.add_stream("acs_board", ACS_COLUMNS)
    tvac = rec.add_stream("tvac", TVAC_COLUMNS, "monitor", rate_hz=1.0)
    rec.start()
    rec.event("run_start", "runner", f"{name}: 3 steps, mode sim", t_s=0.0)
    return rec, board, tvac


def _board_rows(t0: float, t1: float) -> dict[str, np.ndarray]:
    """Board rows at 100 Hz from t0 to t1 (s): gyro z = 0.5 t deg/s (a ramp), temps rising 0.1 degC/s."""
    t = np.arange(round(t0 * RATE_HZ), round(t1 * RATE_HZ)) / RATE_HZ
    n = t.size
    return dict(
        time_s=t, counter=(np.round(t * RATE_HZ) % 65536).astype("u2"), board_time=t + 1000.0,
        gyro=np.c_[np.full(n, 0.01), np.full(n, -0.02), 0.5 * t], accel=np.tile([0.0, 0.0, 1.0], (n, 1)),
        mag=np.tile([20.0, -3.0, 40.0], (n, 1)), temp=np.c_[20 + 0.1 * t, 21 + 0.1 * t, 22 + 0.1 * t],
        status=np.zeros(n, "u2"),
    )


def _tvac_rows(t0: float, t1: float) -> dict[str, np.ndarray]:
    t = np.arange(np.ceil(t0), np.ceil(t1), 1.0)
    return dict(time_s=t, air_temp=20 + 0.2 * t, mount_temp=19 + 0.1 * t, pressure=1e-3 * np.exp(-t / 10))


def _append(rec: RunRecorder, key: str, rows: dict[str, np.ndarray]) -> None:
    rows = dict(rows)
    rec.append(key, rows.pop("time_s"), **rows)


def test_snapshot_while_recording_then_closed(tmp_path: Path) -> None:
    rec, board, tvac = _create(tmp_path)
    rec.event("step_start", "power", "power on", t_s=0.0, step=0)
    _append(rec, board, _board_rows(0.0, 5.0))
    _append(rec, tvac, _tvac_rows(0.0, 5.0))
    rec.event("step_end", "power", "done", t_s=5.0, step=0)
    rec.event("step_start", "record", "rotate at 0.5 deg/s/s", t_s=5.0, step=1)
    _append(rec, board, _board_rows(5.0, 20.0))
    _append(rec, tvac, _tvac_rows(5.0, 20.0))
    rec.event("note", "procedure", "table spinning up", t_s=10.0, step=1)
    rec.tick(20.0)
    rec.flush()

    tracker = StepTracker()
    s = snapshot(rec.path, tracker=tracker)  # the recorder still has the file open in SWMR mode
    assert s.status == "running" and "heartbeat" in s.status_detail and not s.final
    assert s.procedure == "watch_test" and s.mode == "sim"
    assert s.current_step is not None
    assert (s.current_step.index, s.current_step.name, s.current_step.type) == (1, "rotate at 0.5 deg/s/s", "record")
    assert s.current_step.t_start_s == 5.0
    assert (s.steps_done, s.steps_with("failed"), s.steps_total) == (1, 0, 3)
    assert s.run_time_s == pytest.approx(20.0, abs=0.011)
    assert [e.kind for e in s.events][-3:] == ["step_end", "step_start", "note"]
    assert s.events[-1].message == "table spinning up" and s.events_total == 5

    b = s.stream("acs_board")
    assert b.rows == 2000 and b.t_last_s == pytest.approx(19.99)
    assert b.rate_hz == pytest.approx(100.0, rel=1e-6)
    assert b.columns["gyro"] == "deg/s" and b.columns["temp"] == "degC"
    np.testing.assert_allclose(b.latest["gyro"], [0.01, -0.02, 0.5 * 19.99])
    np.testing.assert_allclose(b.latest["temp"], [20 + 1.999, 21 + 1.999, 22 + 1.999])
    assert int(b.latest["counter"]) == 1999
    gz = s.signal("acs_board", "gyro z")
    assert gz.units == "deg/s" and gz.value == pytest.approx(9.995)
    # trend: 40 bins over 0..19.99 s, each the mean of its rows; the ramp 0.5 t gives the bin centres
    t = np.arange(2000) / RATE_HZ
    bins = np.clip(np.floor(t / 19.99 * 40), 0, 39).astype(int)
    expected = np.array([(0.5 * t[bins == k]).mean() for k in range(40)])
    np.testing.assert_allclose(gz.trend, expected)
    assert (gz.trend_min, gz.trend_max) == (pytest.approx(expected[0]), pytest.approx(expected[-1]))
    assert np.all(np.diff(gz.trend) > 0)
    assert s.signal("acs_board", "gyro y").value == pytest.approx(-0.02)
    assert {sig.column for sig in b.signals} == {"gyro", "accel", "mag", "temp", "status"}  # counter, board_time hidden

    m = s.stream("tvac/monitor")
    assert m.rows == 20 and m.rate_hz == pytest.approx(1.0)
    p = s.signal("tvac/monitor", "pressure")
    assert p.units == "Torr" and p.value == pytest.approx(1e-3 * np.exp(-1.9))
    assert s.signal("tvac/monitor", "air_temp").value == pytest.approx(20 + 0.2 * 19)

    # more rows and a failed step: the tracker reads only the new events
    seen = tracker.scanned
    rec.event("step_end", "record", "failed: rate 9.99 deg/s outside 10 +- 0.1", t_s=20.0, step=1)
    rec.event("step_start", "wait", "settle", t_s=20.0, step=2)
    _append(rec, board, _board_rows(20.0, 30.0))
    rec.flush()
    s = snapshot(rec.path, tracker=tracker)
    assert tracker.scanned == seen + 2
    assert s.current_step is not None and (s.current_step.index, s.current_step.name) == (2, "settle")
    assert (s.steps_done, s.steps_with("failed")) == (2, 1)
    assert s.steps[1].detail == "rate 9.99 deg/s outside 10 +- 0.1"
    assert s.stream("acs_board").rows == 3000

    rec.event("step_end", "wait", "done", t_s=30.0, step=2)
    rec.event("run_end", "runner", "completed", t_s=30.0)
    rec.close("completed")
    s = snapshot(rec.path, tracker=tracker)
    assert s.status == "completed" and s.final and s.current_step is None
    assert [(x.name, x.outcome) for x in s.steps] == [("power on", "done"), ("rotate at 0.5 deg/s/s", "failed"), ("settle", "done")]
    assert s.events[-1].kind == "run_end"
    fresh = snapshot(rec.path)  # without a tracker: the same steps from one full scan
    assert [(x.index, x.outcome) for x in fresh.steps] == [(x.index, x.outcome) for x in s.steps]


def test_aborted_and_stale_runs(tmp_path: Path) -> None:
    rec, board, _ = _create(tmp_path / "a")
    rec.event("step_start", "record", "soak", t_s=0.0, step=0)
    _append(rec, board, _board_rows(0.0, 2.0))
    rec.flush()
    later = snapshot(rec.path, now_unix=time.time() + 60.0, stale_after_s=10.0)
    assert later.status == "stale" and "probably crashed" in later.status_detail and not later.final
    assert later.current_step is None and later.steps[0].outcome == "interrupted"
    now = snapshot(rec.path)
    assert now.status == "running" and now.current_step is not None and now.current_step.name == "soak"
    rec.event("step_end", "record", "aborted: SIGINT received (operator stop)", t_s=2.0, step=0)
    rec.event("abort", "runner", "SIGINT received (operator stop)", t_s=2.0)
    rec.close("aborted", "SIGINT received (operator stop)")
    s = snapshot(rec.path)
    assert s.status == "aborted" and s.final and s.abort_reason == "SIGINT received (operator stop)"
    assert s.steps_with("aborted") == 1
    console = Console(record=True, width=120)
    assert watch(rec.path, console, interval_s=0.05) == EXIT_OK  # a finished run: shown once, returns
    text = console.export_text()
    assert "ABORTED" in text and "abort reason: SIGINT received (operator stop)" in text


def test_trend_covers_the_last_window_only(tmp_path: Path) -> None:
    """A 30-minute stream at 10 Hz: the trend spans the last 600 s (read with a stride), values its bin means."""
    rec = RunRecorder.create(tmp_path, procedure_name="long", procedure_text="p", procedure_path="p.yaml",
                             config_text="c", config_path="c.yaml", mode="sim", software_version="test")
    key = rec.add_stream("rate_table", [Column("angle", "deg"), Column("rate", "deg/s")], "monitor", rate_hz=10.0)
    rec.start()
    t = np.arange(18000) / 10.0
    rec.append(key, t, angle=t.copy(), rate=np.where(t < 1500, 1.0, 5.0))
    rec.flush()
    s = snapshot(rec.path, trend_points=30)
    rec.close("completed")
    angle = s.signal("rate_table/monitor", "angle")
    assert len(angle.trend) == 30 and angle.value == pytest.approx(1799.9)
    assert s.stream("rate_table/monitor").trend_span_s == pytest.approx(600.0, abs=0.2)
    np.testing.assert_allclose(angle.trend, 1199.9 + 600 / 30 * (np.arange(30) + 0.5), atol=0.3)
    rate = s.signal("rate_table/monitor", "rate")
    assert (rate.trend_min, rate.trend_max) == (1.0, 5.0)
    assert sparkline(rate.trend) == "▁" * 15 + "█" * 15


def test_sparkline() -> None:
    ramp = sparkline(np.linspace(-3.0, 7.0, 40))
    assert len(ramp) == 40 and ramp[0] == "▁" and ramp[-1] == "█"
    levels = [SPARK_CHARS.index(c) for c in ramp]
    assert levels == sorted(levels) and set(levels) == set(range(8))
    assert sparkline([2.0, 2.0, 2.0]) == "▅▅▅"
    assert sparkline([0.0, float("nan"), 1.0]) == "▁ █"
    assert sparkline([float("nan")] * 3) == "   "
    assert sparkline([0.0, 5.0, 10.0], lo=0.0, hi=20.0) == "▁▃▅"


def test_watch_once_renders_step_and_readings(tmp_path: Path) -> None:
    rec, board, tvac = _create(tmp_path)
    rec.event("step_start", "power", "power on", t_s=0.0, step=0)
    rec.event("step_end", "power", "done", t_s=1.0, step=0)
    rec.event("step_start", "record", "hot plateau soak", t_s=1.0, step=1)
    _append(rec, board, _board_rows(0.0, 12.0))
    _append(rec, tvac, _tvac_rows(0.0, 12.0))
    rec.flush()
    console = Console(record=True, width=120)
    assert watch(rec.path, console, once=True) == EXIT_OK
    rec.close("completed")
    text = console.export_text()
    assert "RUNNING" in text and "watch_test" in text
    assert "step 2/3" in text and "hot plateau soak (record)" in text and "1/3 finished" in text
    assert "gyro x" in text and "mag x" in text and "temp x" in text
    line = next(x for x in text.splitlines() if " 5.995 " in x)  # gyro z: y and z rows repeat no name
    assert line.split()[:4] == ["│", "z", "5.995", "deg/s"] and "▁" in line and "█" in line
    line = next(x for x in text.splitlines() if "air_temp" in x)
    assert "22.2" in line and "degC" in line
    line = next(x for x in text.splitlines() if "pressure" in x)
    assert "3.3287e-04" in line and "Torr" in line and "█▇▆▅▅▄▃▃▂▂▁▁" in line  # 12 rows: 12 points (issue 30: one formatter)
    assert "1,200 rows" in text and "100 Hz" in text
    assert "step_start" in text and "hot plateau soak" in text
    assert max(len(x) for x in text.splitlines()) <= 120


WRITER = textwrap.dedent(
    """
    import sys, time
    import numpy as np
    from pathlib import Path
    from bench.record import Column, RunRecorder
    from bench.errors import RecorderError
    from bench.runner.ingest import ACS_COLUMNS

    rec = RunRecorder.create(Path(sys.argv[1]), procedure_name="cross_process", procedure_text="p", procedure_path="p.yaml",
                             config_text="c", config_path="c.yaml", mode="sim", software_version="test", flush_interval_s=0.05)
    key = rec.add_stream("acs_board", ACS_COLUMNS)
    rec.start()
    rec.event("run_start", "runner", "cross_process: 1 steps, mode sim", t_s=0.0)
    rec.event("step_start", "record", "stream for a while", t_s=0.0, step=0)
    rec.flush()
    print("started", rec.path, flush=True)
    for i in range(30):  # 30 batches of 5 rows, one every 50 ms
        t = (i * 5 + np.arange(5)) / 100.0
        rec.append(key, t, counter=np.arange(i * 5, i * 5 + 5).astype("u2"), board_time=t, gyro=np.c_[t, t, t],
                   accel=np.zeros((5, 3)), mag=np.zeros((5, 3)), temp=np.full((5, 3), 25.0), status=np.zeros(5, "u2"))
        rec.tick(float(t[-1]))
        time.sleep(0.05)
    rec.event("step_end", "record", "done", t_s=1.5, step=0)
    rec.event("run_end", "runner", "completed", t_s=1.5)
    # A reader holds a shared HDF5 file lock while it reads; the recorder's close() reopens the file
    # "r+" to write the status and does not retry yet, so a read at that instant fails the close
    # (retrying a released recorder's close only redoes the reopen).
    for attempt in range(100):
        try:
            rec.close("completed")
            break
        except RecorderError as exc:
            if "errno 11" not in str(exc):
                raise
            time.sleep(0.02)
    print("closed", attempt, flush=True)
    """
)


def test_reader_in_another_process_sees_rows_grow(tmp_path: Path) -> None:
    script = tmp_path / "writer.py"
    script.write_text(WRITER)
    proc = subprocess.Popen([sys.executable, str(script), str(tmp_path / "runs")], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline().strip()
        assert line.startswith("started "), (line, proc.stderr.read() if proc.poll() is not None else "")
        path = Path(line.split(" ", 1)[1])
        tracker = StepTracker()
        rows: list[int] = []
        deadline = time.monotonic() + 0.8
        while time.monotonic() < deadline:
            s = snapshot(path, tracker=tracker)
            assert s.status == "running"
            assert s.current_step is not None and s.current_step.name == "stream for a while"
            b = s.stream("acs_board")
            rows.append(b.rows)
            if b.rows:
                assert int(b.latest["counter"]) == b.rows - 1  # the last complete row, never a half-written one
                assert s.signal("acs_board", "gyro z").value == pytest.approx((b.rows - 1) / 100.0)
            time.sleep(0.05)
        assert rows == sorted(rows) and rows[-1] > rows[0] and len(set(rows)) >= 3, rows
        # then the live view follows the run to its end and returns by itself
        console = Console(record=True, width=120)
        t0 = time.monotonic()
        assert watch(path, console, interval_s=0.1, max_updates=100) == EXIT_OK  # bound: 10 s
        assert time.monotonic() - t0 < 5.0
        assert proc.wait(10) == 0, proc.stderr.read()
        text = console.export_text()
        assert "COMPLETED" in text and "150 rows" in text and "stream for a while" in text
        assert snapshot(path).stream("acs_board").rows == 150
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)


def test_not_a_run_file_gives_one_line_input_error(tmp_path: Path) -> None:
    rec, board, _ = _create(tmp_path / "good")
    _append(rec, board, _board_rows(0.0, 50.0))
    rec.close("completed")
    garbage = tmp_path / "garbage.h5"
    garbage.write_bytes(os.urandom(4096))
    truncated = tmp_path / "truncated.h5"
    truncated.write_bytes(rec.path.read_bytes()[:3000])
    foreign = tmp_path / "foreign.h5"
    with h5py.File(foreign, "w") as f:
        f["x"] = np.arange(3)
    console = Console(record=True, width=120)
    for path in (garbage, truncated, foreign, tmp_path / "a_directory"):
        if path.name == "a_directory":
            path.mkdir()
        with pytest.raises(InputError) as exc:
            snapshot(path)
        msg = str(exc.value)
        assert msg.startswith(f"{path}: not a readable bench run file: ") and "\n" not in msg
        with pytest.raises(InputError):
            watch(path, console, once=True)


def test_missing_file_is_waited_for(tmp_path: Path) -> None:
    console = Console(record=True, width=120)
    missing = tmp_path / "runs" / "not_yet.h5"
    with pytest.raises(InputError, match="no such file$"):
        watch(missing, console, once=True)  # --once does not wait
    t0 = time.monotonic()
    with pytest.raises(InputError, match=r"no such file \(waited 0.3 s for it to appear\)"):
        watch(missing, console, interval_s=0.05, wait_s=0.3)
    assert 0.3 <= time.monotonic() - t0 < 2.0
    assert "waiting up to 0.3 s for" in console.export_text()

    # a finished run file moved into place while watch waits for it
    rec, board, _ = _create(tmp_path / "elsewhere")
    _append(rec, board, _board_rows(0.0, 1.0))
    rec.close("completed")
    missing.parent.mkdir()
    mover = threading.Timer(0.3, shutil.move, args=(str(rec.path), str(missing)))
    mover.start()
    console = Console(record=True, width=120)
    try:
        assert watch(missing, console, interval_s=0.05, wait_s=10.0) == EXIT_OK
    finally:
        mover.join()
    assert "COMPLETED" in console.export_text()


@pytest.mark.signals  # SIGINT must raise KeyboardInterrupt here, as in a terminal, not be ignored as in a background job
def test_ctrl_c_ends_the_live_view_quietly(tmp_path: Path) -> None:
    rec, board, _ = _create(tmp_path)
    rec.event("step_start", "record", "endless soak", t_s=0.0, step=0)
    _append(rec, board, _board_rows(0.0, 1.0))
    rec.flush()
    console = Console(record=True, width=120)
    timer = threading.Timer(0.4, os.kill, args=(os.getpid(), signal.SIGINT))
    timer.start()
    try:
        t0 = time.monotonic()
        assert watch(rec.path, console, interval_s=0.05) == EXIT_OK  # a running file: only Ctrl-C ends it
        assert time.monotonic() - t0 < 5.0
    finally:
        timer.join()
        rec.close("completed")
    assert "endless soak" in console.export_text()


@pytest.mark.signals
def test_ctrl_c_swallowed_by_a_finaliser_still_ends_the_live_view(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """CI, 2026-11-28: the Ctrl-C's KeyboardInterrupt was raised inside a weakref callback, Python
    dropped it ("Exception ignored in ...") and the live view ran on until the test's time limit.
    Here a finaliser that runs during the third read receives the SIGINT: the view ends at the next
    refresh, quietly (no "Exception ignored" traceback), not after its 200 updates."""
    import bench.watch as watch_module

    rec, board, _ = _create(tmp_path)
    rec.event("step_start", "record", "endless soak", t_s=0.0, step=0)
    _append(rec, board, _board_rows(0.0, 1.0))
    rec.flush()

    class SigintInFinaliser:
        def __del__(self) -> None:
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(10_000):  # the handler runs here, inside the finaliser, which drops its exception
                pass

    reads = []
    real_snapshot = watch_module.snapshot

    def snapshot(*args, **kwargs):
        reads.append(time.monotonic())
        if len(reads) == 3:
            SigintInFinaliser()  # collected at once: __del__ runs inside this read
        return real_snapshot(*args, **kwargs)

    monkeypatch.setattr(watch_module, "snapshot", snapshot)
    console = Console(record=True, width=120)
    try:
        assert watch(rec.path, console, interval_s=0.05, max_updates=200) == EXIT_OK
    finally:
        rec.close("completed")
    assert len(reads) == 3, f"{len(reads)} reads: the Ctrl-C was lost"
    assert "Exception ignored" not in capsys.readouterr().err
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # Python's own handler back


def test_max_updates_bounds_the_live_view(tmp_path: Path) -> None:
    rec, board, _ = _create(tmp_path)
    rec.event("step_start", "record", "soak", t_s=0.0, step=0)
    _append(rec, board, _board_rows(0.0, 1.0))
    rec.flush()
    console = Console(record=True, width=120)
    t0 = time.monotonic()
    try:
        assert watch(rec.path, console, interval_s=0.05, max_updates=4) == EXIT_OK
        elapsed = time.monotonic() - t0
    finally:
        rec.close("completed")
    assert 0.15 <= elapsed < 3.0
    assert "RUNNING" in console.export_text()
    with pytest.raises(InputError, match="--interval"):
        watch(rec.path, console, interval_s=0.0)
