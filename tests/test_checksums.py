"""Checksummed run files (issue 21, "Silent damage"): Fletcher-32 on every chunked dataset, a flipped
bit or 100 kB zeroed in the stream data found by ``bench inspect --verify`` with its stream and run
times, and the analyses leaving those rows out (saying so) or refusing, never analysing them."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from bench.errors import InputError
from tests.conftest import dry_run_file, run_cli

# A 6-minute chamber ramp with the board streaming at 100 Hz: 36,000 board rows in chunks of 4096.
RAMP = """schema: bench-procedure/1
name: checksum_ramp
instruments: [acs_board, tvac]
steps:
  - power: {instrument: acs_board, on: true, name: sensors on}
  - configure: {instrument: acs_board, odr: 100 Hz, moving_average: 1}
  - set_temperature: {instrument: tvac, set_point: 30 degC, ramp: 2 degC/min, name: ramp up}
  - record: {instrument: acs_board, duration: 6 min, window: ramp, name: record the ramp}
  - power: {instrument: acs_board, on: false, name: sensors off}
"""
GYRO = "/streams/acs_board/gyro"
TIME = "/streams/acs_board/time"
AIR = "/streams/tvac/monitor/air_temp"


@pytest.fixture(scope="module")
def run_file(tmp_path_factory) -> Path:
    return dry_run_file(tmp_path_factory.mktemp("checksums"), "checksum_ramp", RAMP)


# ---- damaging a copy --------------------------------------------------------------------------
def chunk_extent(path: Path, dataset: str, row: int) -> tuple[int, int, int]:
    """``(file offset, size in bytes, rows per chunk)`` of the chunk of ``dataset`` holding ``row``."""
    with h5py.File(path, "r") as f:
        ds = f[dataset]
        step = ds.chunks[0]
        info = ds.id.get_chunk_info_by_coord((row // step * step,) + (0,) * (ds.ndim - 1))
        return int(info.byte_offset), int(info.size), int(step)


def flipped(src: Path, dst: Path, dataset: str, row: int, bit: int = 3) -> Path:
    """A copy of ``src`` with one bit flipped in the middle of the chunk of ``dataset`` holding ``row``."""
    shutil.copy(src, dst)
    offset, size, _ = chunk_extent(dst, dataset, row)
    with open(dst, "r+b") as fh:
        fh.seek(offset + size // 2)
        byte = fh.read(1)[0]
        fh.seek(offset + size // 2)
        fh.write(bytes([byte ^ (1 << bit)]))
    return dst


def zeroed(src: Path, dst: Path, offset: int, n: int = 100_000) -> Path:
    """A copy of ``src`` with ``n`` bytes from ``offset`` set to zero."""
    shutil.copy(src, dst)
    with open(dst, "r+b") as fh:
        fh.seek(offset)
        fh.write(bytes(n))
    return dst


def times(path: Path, *rows: int) -> list[str]:
    """The run times of ``rows`` of the board stream, as ``bench`` prints them (s, 2 decimals)."""
    with h5py.File(path, "r") as f:
        return [f"{float(f[TIME][r]):.2f}" for r in rows]


def verify(path: Path) -> tuple[int, str, dict]:
    r = run_cli("inspect", str(path), "--verify")
    j = run_cli("inspect", str(path), "--verify", "--json")
    assert "Traceback" not in r.stderr + j.stderr
    assert j.returncode == r.returncode, j.stderr
    return r.returncode, r.stdout + r.stderr, json.loads(j.stdout)


def part(doc: dict, name: str) -> dict:
    (p,) = [p for p in doc["streams"] + doc["events"] if p["name"] == name]
    return p


# ---- the filter ---------------------------------------------------------------------------------
def test_every_chunked_dataset_has_fletcher32(run_file):
    chunked, contiguous = [], []
    with h5py.File(run_file, "r") as f:
        f.visititems(lambda n, o: (chunked if o.chunks else contiguous).append((n, o.fletcher32))
                     if isinstance(o, h5py.Dataset) else None)
    assert chunked and all(has for _n, has in chunked), chunked
    assert {"events", "events_blob", "streams/acs_board/gyro", "streams/tvac/monitor/air_temp"} <= {n for n, _ in chunked}
    # too small to chunk (docs/run-file.md): the texts (scalars) and the 2-value heartbeat
    assert sorted(n for n, _ in contiguous) == ["config/text", "heartbeat", "procedure/text"]
    # the premise of the row ranges below: the board declares no rate, so 4096 rows a chunk
    assert chunk_extent(run_file, GYRO, 4096)[2] == chunk_extent(run_file, TIME, 4096)[2] == 4096
    assert chunk_extent(run_file, AIR, 64)[2] == 64


def test_undamaged_file_verifies(run_file):
    code, out, doc = verify(run_file)
    assert code == 0, out
    assert "verified: all" in out and "FAILED" not in out
    assert doc["status"] == "verified" and doc["damaged_chunks"] == 0 and doc["chunks"] > 0
    assert {p["name"] for p in doc["streams"]} == {"acs_board", "tvac/monitor"}
    assert all(p["status"] == "verified" for p in doc["streams"] + doc["events"])
    assert doc["not_checked"] == ["/heartbeat"] and doc["attributes"] == "verified"  # the texts: in attrs_sha256 (issue 31)


# ---- a flipped bit --------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def flipped_gyro(run_file, tmp_path_factory) -> Path:
    return flipped(run_file, tmp_path_factory.mktemp("flip") / "flipped.h5", GYRO, 4096)


def test_flipped_bit_is_found_with_its_stream_and_time_range(run_file, flipped_gyro):
    t0, t1 = times(run_file, 4096, 8191)
    code, out, doc = verify(flipped_gyro)
    assert code == 1, out
    assert f"rows 4096–8191 (t {t0}–{t1} s): checksum failed (gyro)" in out
    assert "stream acs_board" in out and "FAILED: 1 of" in out
    board = part(doc, "acs_board")
    assert doc["status"] == "failed" and doc["damaged_chunks"] == 1
    assert board["status"] == "failed"
    (d,) = board["damage"]
    assert (d["row_start"], d["row_end"], d["reason"]) == (4096, 8192, "checksum failed (gyro)")
    assert (f"{d['t_start_s']:.2f}", f"{d['t_end_s']:.2f}") == (t0, t1)
    assert part(doc, "tvac/monitor")["status"] == "verified"


def test_plain_inspect_still_works_and_does_not_claim_the_data_verified(flipped_gyro, tmp_path):
    r = run_cli("inspect", str(flipped_gyro))
    assert r.returncode == 0, r.stderr
    text = " ".join(r.stdout.split())
    assert "checksums" in text and "not read by this summary" in text and "--verify" in text
    j = run_cli("inspect", str(flipped_gyro), "--json")
    assert json.loads(j.stdout)["checksums"] == "all"
    # damage the summary does read (the first run time) is shown, not an unreadable file
    first = flipped(flipped_gyro, tmp_path / "first.h5", TIME, 0)
    r = run_cli("inspect", str(first))
    assert r.returncode == 0, r.stderr
    assert "stream acs_board: the run time of row 0 fails its checksum" in " ".join(r.stdout.split())
    doc = json.loads(run_cli("inspect", str(first), "--json").stdout)
    (board,) = [s for s in doc["streams"] if s["key"] == "acs_board"]
    assert board["damage"] and board["t_start_s"] is None


def test_diagnose_and_calibrate_leave_the_damaged_rows_out_and_say_so(run_file, flipped_gyro):
    t0, t1 = times(run_file, 4096, 8191)
    note = f"excluded rows 4096–8191 of stream acs_board (t {t0}–{t1} s): checksum failed (gyro)"
    d = run_cli("diagnose", str(flipped_gyro), "--json", timeout=300)
    assert d.returncode == 0, d.stderr
    assert note in d.stderr
    json.loads(d.stdout)  # stdout stays clean JSON
    c = run_cli("calibrate", "thermal", str(flipped_gyro), "--json", timeout=300)
    assert c.returncode == 0, c.stderr
    assert note in c.stderr


def test_dataset_has_none_of_the_damaged_rows(run_file, flipped_gyro):
    from bench.analysis.dataset import load_dataset

    clean, damaged = load_dataset(run_file), load_dataset(flipped_gyro)
    assert clean.notes == []
    assert len(damaged) == len(clean) - 4096
    t0, t1 = (float(x) for x in times(run_file, 4096, 8191))
    t = damaged["time_s"]
    assert not np.any((t >= t0) & (t <= t1))
    assert any("excluded rows 4096–8191" in n for n in damaged.notes)


def test_read_stream_refuses_damaged_rows_and_read_stream_checked_leaves_them_out(run_file, flipped_gyro):
    from bench.record.reader import read_stream, read_stream_checked

    with pytest.raises(InputError, match=r"damaged data: rows 4096–8191 of stream acs_board \(t .*\): checksum failed \(gyro\)"):
        read_stream(flipped_gyro, "acs_board")
    read_stream(flipped_gyro, "acs_board", ("temp",))  # the damaged column not asked for: nothing to refuse
    got = read_stream_checked(flipped_gyro, "acs_board", ("gyro",))
    full = read_stream(run_file, "acs_board", ("gyro",))
    keep = np.r_[0:4096, 8192:full["time"].shape[0]]
    np.testing.assert_array_equal(got.data["gyro"], full["gyro"][keep])
    np.testing.assert_array_equal(got.data["time"], full["time"][keep])
    assert [(e.row_start, e.row_end) for e in got.excluded] == [(4096, 8192)]


def test_report_refuses_a_damaged_file_with_a_located_message(flipped_gyro, tmp_path):
    r = run_cli("report", str(flipped_gyro), "-o", str(tmp_path / "out.html"), timeout=300)
    assert r.returncode == 2, r.stdout + r.stderr
    assert "Traceback" not in r.stderr
    assert "rows 4096–8191 of stream acs_board" in r.stderr and "checksum failed (gyro)" in r.stderr
    assert not (tmp_path / "out.html").exists()


def test_damaged_monitor_chunk_leaves_out_the_board_rows_of_its_gap(run_file, tmp_path):
    from bench.analysis.dataset import load_dataset

    damaged = flipped(run_file, tmp_path / "monitor.h5", AIR, 64)
    code, out, doc = verify(damaged)
    assert code == 1 and "checksum failed (air_temp)" in out
    (gap,) = part(doc, "tvac/monitor")["damage"]
    ds = load_dataset(damaged)
    t = ds["time_s"]
    assert not np.any((t > gap["t_before_s"]) & (t < gap["t_after_s"]))  # no chamber value interpolated across it
    assert any("excluded rows 64–127 of stream tvac/monitor" in n for n in ds.notes)
    assert any("inside that gap of stream tvac/monitor" in n for n in ds.notes)


def test_damaged_event_chunk_is_reported_and_the_summary_still_reads(run_file, tmp_path):
    damaged = flipped(run_file, tmp_path / "events.h5", "/events", 1024)
    code, out, doc = verify(damaged)
    assert code == 1 and part(doc, "/events")["status"] == "failed"
    r = run_cli("inspect", str(damaged))
    assert r.returncode == 0, r.stderr
    assert "of /events: checksum failed" in " ".join(r.stdout.split())


# ---- 100 kB zeroed --------------------------------------------------------------------------------
def test_100_kb_zeroed_from_the_middle_of_a_time_chunk(run_file, tmp_path):
    offset, size, step = chunk_extent(run_file, TIME, 4096)
    damaged = zeroed(run_file, tmp_path / "zeroed_time.h5", offset + size // 2)
    code, out, doc = verify(damaged)
    assert code == 1, out
    (d,) = part(doc, "acs_board")["damage"]
    # the chunk it starts in fails its checksum; the time chunks it covers whole read as zeros
    # (Fletcher-32 of zeros is zero), which run times cannot be
    assert d["row_start"] == 4096 and d["row_end"] >= 4096 + 3 * step
    assert "checksum failed (time)" in d["reason"] and "zeroed on disk (time)" in d["reason"]
    assert d["t_start_s"] is None and f"{d['t_before_s']:.2f}" == times(run_file, 4095)[0]
    r = run_cli("diagnose", str(damaged), "--json", timeout=300)
    assert r.returncode == 0, r.stderr
    assert f"excluded rows 4096–{d['row_end'] - 1} of stream acs_board (t between" in r.stderr


def test_100_kb_zeroed_over_a_whole_data_chunk_and_its_checksum(run_file, tmp_path):
    offset, size, step = chunk_extent(run_file, GYRO, 4096)
    assert size < 100_000  # the gyro chunk at rows 4096-8191 is zeroed whole, checksum included
    damaged = zeroed(run_file, tmp_path / "zeroed_gyro.h5", offset)
    with h5py.File(damaged, "r") as f:  # what HDF5 alone makes of it: zeros that pass the checksum
        assert not f[GYRO][4096:8192].any()
    code, out, doc = verify(damaged)
    assert code == 1, out
    (d,) = part(doc, "acs_board")["damage"]
    assert (d["row_start"], d["row_end"]) == (4096, 4096 + 2 * step)
    assert d["reason"] == "zeroed on disk (gyro); checksum failed (gyro)" or d["reason"] == "checksum failed (gyro); zeroed on disk (gyro)"
    from bench.analysis.dataset import load_dataset

    ds = load_dataset(damaged)
    assert len(ds) == len(load_dataset(run_file)) - 2 * step
    assert not np.any(np.all(np.column_stack([ds[f"gyro_{a}_dps"] for a in "xyz"]) == 0.0, axis=1))


def test_true_zero_data_is_not_taken_for_damage(tmp_path):
    from bench.record import Column, RunRecorder

    rec = RunRecorder.create(tmp_path, procedure_name="zeros", procedure_text="", procedure_path="", config_text="",
                             config_path="", mode="sim", software_version="0")
    key = rec.add_stream("daq", [Column("idle", "V"), Column("flag", "1", "u1"), Column("signal", "V")], rate_hz=100.0)
    rec.start()
    t = np.arange(3000) / 100.0
    rec.append(key, t, idle=np.zeros(3000), flag=np.zeros(3000, dtype=np.uint8), signal=np.sin(t))
    rec.close("completed")
    code, out, doc = verify(rec.path)
    assert code == 0, out
    assert part(doc, "daq")["status"] == "verified"
    # the same file with a bit flipped in the zero column: found, and only that chunk
    damaged = flipped(rec.path, tmp_path / "flag.h5", "/streams/daq/idle", 200)
    code, out, doc = verify(damaged)
    assert code == 1
    (d,) = part(doc, "daq")["damage"]
    assert (d["row_start"], d["row_end"], d["reason"]) == (200, 400, "checksum failed (idle)")


def test_a_file_being_written_verifies_while_rows_are_extended_but_not_written_yet(tmp_path):
    """A reader of a live file sees a resized dataset before its rows are written (fill values,
    zeros): not damage, not even in the ``time`` column."""
    from bench.record import Column, RunRecorder

    rec = RunRecorder.create(tmp_path, procedure_name="live", procedure_text="", procedure_path="", config_text="",
                             config_path="", mode="sim", software_version="0")
    key = rec.add_stream("daq", [Column("v", "V")], rate_hz=100.0)
    rec.start()
    try:
        t = np.arange(1000) / 100.0 + 1.0
        rec.append(key, t, v=np.sin(t))
        rec.flush()
        for ds in rec._streams[key].datasets.values():  # what a flush does between resize and write
            ds.resize(1600, axis=0)
        rec._f.flush()
        code, out, doc = verify(rec.path)
        assert code == 0, out
        assert part(doc, "daq")["rows"] == 1600
        r = run_cli("inspect", str(rec.path), "--json")
        assert r.returncode == 0, r.stderr
    finally:
        rec.close("completed")


# ---- files written before checksums, unreadable files --------------------------------------------
def test_file_without_checksums_reads_as_unverified(tmp_path, monkeypatch):
    from bench.record import Column, RunRecorder

    create = h5py.Group.create_dataset

    def without_checksum(self, name, *args, **kw):
        kw.pop("fletcher32", None)
        return create(self, name, *args, **kw)

    monkeypatch.setattr(h5py.Group, "create_dataset", without_checksum)
    rec = RunRecorder.create(tmp_path, procedure_name="old", procedure_text="", procedure_path="", config_text="",
                             config_path="", mode="sim", software_version="0")
    key = rec.add_stream("daq", [Column("v", "V")])
    rec.start()
    rec.append(key, np.arange(10.0), v=np.arange(10.0))
    rec.close("completed")
    monkeypatch.undo()
    with h5py.File(rec.path, "r") as f:
        assert not f["streams/daq/v"].fletcher32
    code, out, doc = verify(rec.path)
    assert code == 1, out
    assert "UNVERIFIED" in out and "verified: all" not in out
    assert doc["status"] == "unverified" and part(doc, "daq")["status"] == "unverified"
    r = run_cli("inspect", str(rec.path))
    assert r.returncode == 0 and "written before checksums" in " ".join(r.stdout.split())


def test_verify_of_an_unreadable_file_is_exit_2(tmp_path):
    bad = tmp_path / "not_a_run.h5"
    bad.write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(100))
    r = run_cli("inspect", str(bad), "--verify")
    assert r.returncode == 2 and "not a readable bench run file" in r.stderr and "Traceback" not in r.stderr
