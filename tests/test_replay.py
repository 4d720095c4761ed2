"""bench replay: recorded sessions replay to the same decisions and results; edits are caught."""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import h5py
import pytest
from rich.console import Console

from bench.errors import EXIT_FAILED, EXIT_OK, InputError
from bench.record import read_run_summary
from bench.replay import replay
from bench.replay.cli import cmd_replay
from drivers import acs_protocol

SESSIONS = Path(__file__).resolve().parent / "sessions"
RATE = SESSIONS / "rate_transfer_short.h5"
ABORT = SESSIONS / "chamber_interlock_abort.h5"


def _cli(tmp_path: Path, run_file: Path, procedure: Path | None = None) -> tuple[int, str]:
    console = Console(record=True, width=200)
    rc = cmd_replay(argparse.Namespace(run_file=run_file, procedure=procedure, runs_dir=tmp_path / "replays"), console)
    return rc, console.export_text()


@pytest.mark.parametrize("session", sorted(SESSIONS.glob("*.h5")), ids=lambda p: p.stem)
def test_every_recorded_session_replays_to_the_same_results(session: Path, tmp_path: Path):
    rc, text = _cli(tmp_path, session)
    assert rc == EXIT_OK, text
    assert "MATCH" in text


def test_replay_is_recorded_as_a_replay_linked_to_its_source(tmp_path: Path):
    result = replay(RATE, runs_dir=tmp_path)
    assert result.ok
    summary = read_run_summary(result.replay_file)
    assert summary.attrs["mode"] == "replay"
    (link,) = [e for e in summary.events if e.kind == "replay"]
    info = json.loads(link.data)
    assert info["source"] == str(RATE.resolve()) and len(info["sha256"]) == 64 and info["source_mode"] == "sim"
    src = read_run_summary(RATE)
    assert [(s.name, s.outcome) for s in summary.steps] == [(s.name, s.outcome) for s in src.steps]
    assert {s.key: s.rows for s in summary.streams} == {s.key: s.rows for s in src.streams}


def test_changed_rate_is_reported_with_step_instrument_and_bytes(tmp_path: Path):
    text = (SESSIONS / "rate_transfer_short.yaml").read_text()
    edited = tmp_path / "rate_transfer_edited.yaml"
    edited.write_text(text.replace("rates: [1 deg/s, 0.5 deg/s,", "rates: [1 deg/s, 0.6 deg/s,"))
    rc, out = _cli(tmp_path, RATE, edited)
    assert rc == EXIT_FAILED
    assert "DIVERGED" in out and "instrument rate_table" in out and "rate +0.6 deg/s" in out
    assert "expected: SDO write 0x60FF target_velocity [06 01 23 ff 60 00 f4 01 00 00]" in out  # 500 mdeg/s
    assert "got:      SDO write 0x60FF target_velocity [06 01 23 ff 60 00 58 02 00 00]" in out  # 600 mdeg/s
    assert "more divergence(s)" in out


def test_changed_dwell_is_caught(tmp_path: Path):
    text = (SESSIONS / "rate_transfer_short.yaml").read_text()
    edited = tmp_path / "rate_transfer_dwell.yaml"
    edited.write_text(text.replace("  dwell: 2 s", "  dwell: 3 s"))
    result = replay(RATE, edited, tmp_path)
    assert not result.ok
    first = result.divergences[0]
    # the recording stopped the board after the 2 s reference; the replay keeps recording
    assert first.what == "command" and first.instrument == "acs_board" and first.step_name == "zero-rate reference (before)"
    assert first.expected.startswith("STOP_STREAM") and "at 7.000000 s" in first.expected and "at 7.000000 s" not in first.got


def test_changed_command_encoding_of_a_driver_is_caught(tmp_path: Path, monkeypatch):
    original = acs_protocol.encode_frame

    def sensor_power_with_extra_byte(ftype: int, payload: bytes = b"") -> bytes:
        if ftype == acs_protocol.FrameType.SENSOR_POWER:
            payload = bytes([payload[0] * 2])  # a "new encoding": on = 2
        return original(ftype, payload)

    monkeypatch.setattr(acs_protocol, "encode_frame", sensor_power_with_extra_byte)
    result = replay(RATE, runs_dir=tmp_path)
    assert not result.ok
    first = result.divergences[0]
    assert first.instrument == "acs_board" and "SENSOR_POWER" in first.expected and "SENSOR_POWER" in first.got
    assert first.expected != first.got


def test_replay_of_an_aborted_session_reproduces_the_abort(tmp_path: Path):
    src = read_run_summary(ABORT)
    assert src.status == "aborted" and "interlock" in src.abort_reason
    result = replay(ABORT, runs_dir=tmp_path)
    assert result.ok, result.report()
    assert result.status == "aborted" and result.abort_reason == src.abort_reason
    rep = read_run_summary(result.replay_file)
    assert [e.source for e in rep.events if e.kind == "safe_state"] == [e.source for e in src.events if e.kind == "safe_state"]


def test_a_file_of_an_older_format_version_gives_one_clear_line(tmp_path: Path):
    old = tmp_path / "old.h5"
    shutil.copy(RATE, old)
    with h5py.File(old, "r+") as f:
        f.attrs["format_version"] = 0
    with pytest.raises(InputError) as err:
        replay(old, runs_dir=tmp_path)
    msg = err.value.one_line()
    assert "format_version 0 is older" in msg and "\n" not in msg


def test_a_file_without_the_procedure_event_is_refused_clearly(tmp_path: Path):
    not_run = tmp_path / "notes.h5"
    not_run.write_bytes(b"not hdf5 at all")
    with pytest.raises(InputError) as err:
        replay(not_run, runs_dir=tmp_path)
    assert "not a readable bench run file" in err.value.one_line()


def test_replay_of_a_crashed_wall_clock_run_matches_up_to_the_crash(tmp_path: Path):
    """A `--realtime` run killed with SIGKILL: replayed up to its last event, commands in order."""
    import signal

    from tests.test_cli_end_to_end import _start_realtime, _wait_for_rows

    p, runs = _start_realtime(tmp_path, 60)
    try:
        path = _wait_for_rows(runs, 200)
        p.send_signal(signal.SIGKILL)
        p.wait(timeout=10)
    finally:
        if p.poll() is None:
            p.kill()
    assert read_run_summary(path, stale_after_s=0).status == "crashed"
    result = replay(path, runs_dir=tmp_path / "replays")
    assert result.ok, result.report()
