"""A disk another process fills during a run: the run file is finalised (aborted), every row the
recorder accepted is in it, and `bench inspect` reports them (issue 21, part 2).

The disk is a small tmpfs the test mounts (root only; skipped with the reason elsewhere), filled
by the test with a filler file up to ENOSPC, as another process would.
"""

from __future__ import annotations

import errno
import os
import shutil
import subprocess
import sys
import time
import uuid
from pathlib import Path

import h5py
import numpy as np
import pytest

from bench import __version__
from bench.errors import InputError, RecorderError
from bench.record import Column, RunRecorder, read_run_summary, read_stream
from bench.record.space import reserve_path
from tests.conftest import ROOT, SIM_CONFIG, run_cli, write_procedure


@pytest.fixture
def small_disk(tmp_path: Path):
    """A directory on its own 64-MiB tmpfs (the run's free-space check wants 50 MB + its estimate)."""
    mnt = tmp_path / "disk"
    mnt.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a small tmpfs needs root (full-disk tests run where they can mount one)")
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64m", "tmpfs", str(mnt)], capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs: {r.stderr.strip() or r.returncode}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def fill(directory: Path) -> Path:
    """Fill the file system of ``directory`` to ENOSPC with a filler file, as another process would."""
    filler = directory / f"filler-{uuid.uuid4().hex}"
    with open(filler, "wb", buffering=0) as fh:
        for block in (1 << 20, 4096, 512):
            try:
                while True:
                    fh.write(bytes(block))
            except OSError as exc:
                if exc.errno != errno.ENOSPC:
                    raise
    assert shutil.disk_usage(directory).free < 4096
    return filler


def _recorder(directory: Path) -> tuple[RunRecorder, str, list[float]]:
    wall = [0.0]
    rec = RunRecorder.create(directory, procedure_name="full_disk", procedure_text="p", procedure_path="p.yaml",
                             config_text="c", config_path="c.yaml", mode="sim", software_version=__version__,
                             wall_clock=lambda: wall[0])
    key = rec.add_stream("daq", [Column(f"ch{i}", "V") for i in range(4)], rate_hz=1000.0)
    rec.start()
    return rec, key, wall


def _append_seconds(rec: RunRecorder, key: str, wall: list[float], start_s: int, seconds: int, flush: bool) -> None:
    """1000 rows per second of run time; a flush per second when ``flush``."""
    for s in range(start_s, start_s + seconds):
        t = s + np.arange(1000) / 1000.0
        rec.append(key, t, **{f"ch{i}": np.full(1000, float(s)) for i in range(4)})
        if flush:
            wall[0] += 1.0
            rec.tick(float(s + 1))


def test_disk_filled_by_another_process_aborts_with_every_accepted_row(small_disk: Path) -> None:
    rec, key, wall = _recorder(small_disk)
    assert reserve_path(rec.path).stat().st_size == rec.reserve_bytes() > 1024 * 1024
    _append_seconds(rec, key, wall, 0, 5, flush=True)
    _append_seconds(rec, key, wall, 5, 1, flush=False)  # accepted, not flushed yet
    fill(small_disk)
    wall[0] += 1.0
    with pytest.raises(RecorderError, match="disk nearly full"):
        rec.tick(6.0)
    rec.event("abort", "runner", "disk nearly full", t_s=6.0)
    rec.close("aborted", "disk nearly full")  # finalised from the reserve
    assert not reserve_path(rec.path).exists()

    s = read_run_summary(rec.path)
    assert s.status == "aborted" and s.abort_reason == "disk nearly full"
    assert [x.rows for x in s.streams] == [6000] == [rec.rows_written(key)]
    assert s.events[-1].kind == "abort"
    data = read_stream(rec.path, key)
    assert np.array_equal(data["time"], np.concatenate([s_ + np.arange(1000) / 1000.0 for s_ in range(6)]))
    assert np.array_equal(data["ch3"], np.repeat(np.arange(6.0), 1000))
    with h5py.File(rec.path, "r") as f:  # plain h5py opens it too, not only the SWMR reader
        assert f["streams/daq"].attrs["rows_appended"] == 6000
    r = run_cli("inspect", str(rec.path))
    assert r.returncode == 0, r.stderr
    assert "aborted" in r.stdout and "6000" in r.stdout


def test_disk_filled_before_a_normal_close_completes_from_the_reserve(small_disk: Path) -> None:
    rec, key, wall = _recorder(small_disk)
    _append_seconds(rec, key, wall, 0, 3, flush=True)
    _append_seconds(rec, key, wall, 3, 1, flush=False)
    fill(small_disk)
    rec.close("completed")  # the last flush and the status fit in the reserve
    s = read_run_summary(rec.path)
    assert s.status == "completed"
    assert [x.rows for x in s.streams] == [4000]


def test_reserve_that_cannot_be_allocated_refuses_the_file(small_disk: Path) -> None:
    filler = fill(small_disk)
    os.truncate(filler, filler.stat().st_size - 256 * 1024)  # room for the file, not for its reserve
    with pytest.raises(RecorderError, match="disk nearly full: no room for the 1.0 MB kept to finalise the file"):
        _recorder(small_disk)
    assert [p.name for p in small_disk.iterdir() if not p.name.startswith("filler-")] == []


def test_file_left_open_for_writing_is_not_reported_as_empty(tmp_path: Path) -> None:
    """What a writer killed while it finalised the status (or whose finalising failed) leaves: HDF5
    refuses the file. `bench inspect` says so, with its size, and never that nothing was recorded."""
    rec, key, wall = _recorder(tmp_path)
    _append_seconds(rec, key, wall, 0, 3, flush=True)
    rec.close("completed")
    code = ("import h5py, os, sys\n"
            "f = h5py.File(sys.argv[1], 'r+', libver='latest')\n"
            "f.attrs['status'] = 'aborted'\nf.flush()\nos._exit(0)\n")
    subprocess.run([sys.executable, "-c", code, str(rec.path)], check=True, timeout=60)
    with pytest.raises(InputError) as info:
        read_run_summary(rec.path)
    size = f"{rec.path.stat().st_size:,} bytes"
    r = run_cli("inspect", str(rec.path))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    for msg in (str(info.value), r.stderr):
        assert "nothing was recorded" not in msg and "had not started" not in msg
        assert "open for writing outside SWMR mode" in msg and size in msg and "damaged" in msg


def test_run_on_a_disk_filled_during_recording(small_disk: Path, tmp_path: Path) -> None:
    """`bench run` while another process fills the disk: aborted, finalised, its rows readable."""
    proc = write_procedure(tmp_path / "stationary.yaml",
                           "  - power: {instrument: acs_board, on: true}\n  - record: {instrument: acs_board, duration: 20 s}\n")
    runs = small_disk / "runs"
    p = subprocess.Popen(
        [sys.executable, "-m", "bench", "run", str(proc), "--config", str(SIM_CONFIG), "--sim", "--realtime", "--runs-dir", str(runs)],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        deadline = time.monotonic() + 60
        path = None
        while time.monotonic() < deadline:
            files = list(runs.glob("*.h5")) if runs.exists() else []
            if files:
                try:
                    if read_run_summary(files[0]).streams[0].rows >= 100:
                        path = files[0]
                        break
                except (InputError, IndexError):
                    pass
            time.sleep(0.1)
        assert path is not None, "no recorded rows within 60 s"
        fill(small_disk)
        out, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 1, out + err
    assert "Traceback" not in out + err and "could not be finalised" not in out + err
    assert "disk nearly full" in out
    s = read_run_summary(path)
    assert s.status == "aborted" and "disk nearly full" in s.abort_reason
    rows = s.streams[0].rows
    with h5py.File(path, "r") as f:
        assert int(f["streams/acs_board"].attrs["rows_appended"]) == rows >= 100  # every accepted row is in the file
    assert len(read_stream(path, "acs_board")["time"]) == rows
    assert not reserve_path(path).exists()
    r = run_cli("inspect", str(path))
    assert r.returncode == 0, r.stderr
    assert "aborted" in r.stdout and str(rows) in r.stdout


def test_a_new_run_removes_the_reserves_killed_runs_left(tmp_path: Path) -> None:
    """SIGKILL leaves a run's reserve file; the next run in that directory deletes it, and only it."""
    import time

    from bench.record import RunRecorder
    from bench.record.space import STALE_RESERVE_AFTER_S, reserve_path

    killed = tmp_path / "20260101T000000Z_killed.h5"
    killed.write_bytes(b"x")
    old = time.time() - STALE_RESERVE_AFTER_S - 5
    os.utime(killed, (old, old))
    live = tmp_path / "20260101T000001Z_live.h5"
    live.write_bytes(b"x")
    orphan = tmp_path / ".20260101T000002Z_gone.h5.reserve"
    for p in (reserve_path(killed), reserve_path(live), orphan):
        p.write_bytes(b"\0" * 1024)
    rec = RunRecorder.create(tmp_path, procedure_name="next", procedure_text="p", procedure_path="p.yaml",
                             config_text="c", config_path="c.yaml", mode="sim", software_version="test")
    try:
        assert not reserve_path(killed).exists() and not orphan.exists()
        assert reserve_path(live).exists()  # its run file is being written
        assert reserve_path(rec.path).exists()
    finally:
        rec.close("aborted", "test")
