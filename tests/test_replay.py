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
from drivers.board_frames import FrameDescription

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
    original = FrameDescription.encode_frame

    def sensor_power_with_extra_byte(self, ftype: int, payload: bytes = b"") -> bytes:
        if ftype == acs_protocol.FrameType.SENSOR_POWER:
            payload = bytes([payload[0] * 2])  # a "new encoding": on = 2
        return original(self, ftype, payload)

    monkeypatch.setattr(FrameDescription, "encode_frame", sensor_power_with_extra_byte)  # what the driver's frames are made with
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


def test_the_stored_procedure_its_calls_and_profiles_come_from_the_run_file(tmp_path: Path):
    """The replay reads the stored procedure, its sub-procedures and its vibration profiles from
    the texts in the run file (placed in a private directory), not from the paths they were
    recorded at: a run recorded with relative paths replays the same after its lab directory is
    gone. The board's samples are checked against a re-simulation of the dry-run."""
    from tests.conftest import SIM_CONFIG, run_cli

    lab = tmp_path / "lab"
    (lab / "procedures").mkdir(parents=True)
    (lab / "configs" / "vibration").mkdir(parents=True)
    profile = Path(__file__).resolve().parents[1] / "configs" / "vibration" / "low_level_sine_sweep.yaml"
    shutil.copy(profile, lab / "configs" / "vibration" / "sweep.yaml")
    (lab / "procedures" / "main.yaml").write_text(
        "schema: bench-procedure/1\nname: vibe_short\ninstruments: [acs_board]\nsteps:\n"
        "  - power: {instrument: acs_board, on: true}\n  - call: {procedure: sub.yaml}\n"
        "  - vibrate: {profile: ../configs/vibration/sweep.yaml, axis: z, name: sweep, record: acs_board}\n"
        "  - power: {instrument: acs_board, on: false}\n")
    (lab / "procedures" / "sub.yaml").write_text(
        "schema: bench-procedure/1\nname: sub\ninstruments: [acs_board]\nsteps:\n"
        "  - record: {instrument: acs_board, duration: 2 s, window: still}\n")
    r = run_cli("run", "procedures/main.yaml", "--config", str(SIM_CONFIG), "--sim", "--runs-dir", str(tmp_path / "runs"), cwd=lab, timeout=300)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    (run_file,) = (tmp_path / "runs").glob("*.h5")
    info = json.loads(next(e for e in read_run_summary(run_file).events if e.kind == "procedure").data)
    assert {Path(p).name for p in info["sources"]} == {"sub.yaml", "sweep.yaml"}  # the profile's text is kept too
    shutil.rmtree(lab)
    rc, out = _cli(tmp_path, run_file)
    assert rc == EXIT_OK and "MATCH" in out, out
    assert "board samples (acs_board) checked against a re-simulation of the dry-run" in out and "the same" in out, out


LAB_PROCEDURE = """schema: bench-procedure/1
name: lab_short
instruments: [acs_board]
steps:
  - power: {instrument: acs_board, on: true, name: sensors on}
  - record: {instrument: acs_board, duration: 2 s, window: still, name: still}
  - power: {instrument: acs_board, on: false, name: sensors off}
"""


def _lab_run(tmp_path: Path) -> tuple[Path, Path]:
    """A dry-run with a lab config in its own directory whose sensor model and calibration file
    lie next to it (not the shipped ones: a number changed, another name); (run file, lab dir)."""
    from tests.conftest import SIM_CONFIG, run_cli

    root = Path(__file__).resolve().parents[1]
    lab = tmp_path / "mylab"
    (lab / "models").mkdir(parents=True)
    model = (root / "configs" / "sensors" / "acs_board_simple.yaml").read_text()
    assert "gyro_noise_density_dps_rthz: 0.005" in model
    (lab / "models" / "our_board.yaml").write_text(model.replace("gyro_noise_density_dps_rthz: 0.005", "gyro_noise_density_dps_rthz: 0.0071"))
    cal = (root / "configs" / "sensors" / "npsat1_qrs11_ground.yaml").read_text()
    (lab / "models" / "our_gyro_cal.yaml").write_text(cal)
    config = SIM_CONFIG.read_text()
    assert "sensor_model: sensors/acs_board_simple.yaml" in config
    config = config.replace("sensor_model: sensors/acs_board_simple.yaml", "sensor_model: models/our_board.yaml")
    config = config.replace("    timeout: 0.5 s\n    sim:\n      backend: acs_board",
                            "    timeout: 0.5 s\n    calibration: models/our_gyro_cal.yaml\n    sim:\n      backend: acs_board", 1)
    assert "calibration: models/our_gyro_cal.yaml" in config
    (lab / "lab.yaml").write_text(config)
    (lab / "lab_short.yaml").write_text(LAB_PROCEDURE)
    r = run_cli("run", "lab_short.yaml", "--config", "lab.yaml", "--runs-dir", str(tmp_path / "runs"), cwd=lab, timeout=300)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    (run_file,) = (tmp_path / "runs").glob("*.h5")
    return run_file, lab


def _edit_config_sources(run_file: Path, change) -> None:
    """Replace the data of ``run_file``'s 'config_sources' event with ``change(its JSON)``, as a
    hostile or damaged file would have it."""
    import numpy as np

    from bench.record import layout

    with h5py.File(run_file, "r+") as f:
        rows, blob = f[layout.EVENTS], f[layout.EVENTS_BLOB]
        (i,) = np.flatnonzero(rows["kind"][:] == layout.EVENT_CONFIG_SOURCES.encode())
        row = rows[i]
        info = json.loads(blob[row["data_off"]:row["data_off"] + row["data_len"]].tobytes())
        data = json.dumps(change(info)).encode()
        at = blob.shape[0]
        blob.resize((at + len(data),))
        blob[at:] = np.frombuffer(data, dtype=np.uint8)
        row["data_off"], row["data_len"] = at, len(data)
        rows[i] = row


def test_a_lab_configs_own_sensor_model_and_calibration_come_from_the_run_file(tmp_path: Path):
    """A lab config names a sensor model and a calibration file next to it (the normal case): the
    run file keeps their texts ('config_sources' event), so the run replays after the lab
    directory is gone, with the recorded model (the board check re-simulates with it)."""
    run_file, lab = _lab_run(tmp_path)
    summary = read_run_summary(run_file)
    (event,) = [e for e in summary.events if e.kind == "config_sources"]
    info = json.loads(event.data)
    assert info["path"] == str((lab / "lab.yaml").resolve())
    assert {Path(p).name for p in info["sources"]} == {"our_board.yaml", "our_gyro_cal.yaml"}
    assert "0.0071" in info["sources"][str((lab / "models" / "our_board.yaml").resolve())]
    shutil.rmtree(lab)
    rc, out = _cli(tmp_path, run_file)
    assert rc == EXIT_OK and "MATCH" in out, out
    assert "board samples (acs_board) checked against a re-simulation of the dry-run" in out and "the same" in out, out


def test_the_recorded_sensor_model_text_is_the_one_replayed(tmp_path: Path):
    """The board check re-simulates with the sensor model text kept in the run file: that text
    changed in the file (another noise density) makes the re-simulated board samples differ."""
    run_file, lab = _lab_run(tmp_path)
    shutil.rmtree(lab)
    _edit_config_sources(run_file, lambda info: {**info, "sources": {k: v.replace("0.0071", "0.0072") for k, v in info["sources"].items()}})
    rc, out = _cli(tmp_path, run_file)
    assert rc == EXIT_FAILED and "DIVERGED" in out and "stream acs_board column gyro" in out, out
    assert "re-simulated dry-run" in out, out


def test_a_config_sources_path_with_dotdot_is_refused(tmp_path: Path, capsys):
    """A crafted 'config_sources' event whose config path or source path has '..' is refused
    before anything is written: exit 2, one line naming the run file and the event."""
    from bench.cli import main
    from bench.errors import EXIT_BAD_INPUT

    run_file, lab = _lab_run(tmp_path)
    shutil.rmtree(lab)
    for label, change in (("source key", lambda info: {**info, "sources": {f"{lab}/../../etc/evil.yaml": "x: 1\n"}}),
                          ("config path", lambda info: {**info, "path": f"{lab}/../lab.yaml"})):
        crafted = tmp_path / f"crafted_{label.replace(' ', '_')}.h5"
        shutil.copy(run_file, crafted)
        _edit_config_sources(crafted, change)
        capsys.readouterr()
        rc = main(["replay", str(crafted), "--runs-dir", str(tmp_path / "replays")])
        out, err = capsys.readouterr()
        assert rc == EXIT_BAD_INPUT, (label, out, err)
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(str(crafted)), (label, err)
        assert "'config_sources' event" in lines[0] and "'..'" in lines[0], (label, err)
        assert "Traceback" not in err and not (tmp_path / "etc").exists(), (label, err)


def test_a_run_file_recorded_before_config_sources_says_so(tmp_path: Path, capsys):
    """A run file without the 'config_sources' event (recorded before bench kept the config's
    files) replays as before: the files the config names come from the project's configs/ only;
    a lab's own sensor model is "not found", and the message says why."""
    from bench.cli import main
    from bench.errors import EXIT_BAD_INPUT
    from bench.record import layout

    run_file, lab = _lab_run(tmp_path)
    shutil.rmtree(lab)
    with h5py.File(run_file, "r+") as f:  # as an older bench wrote it: no such event
        rows = f[layout.EVENTS]
        kinds = rows["kind"][:]
        kinds[kinds == layout.EVENT_CONFIG_SOURCES.encode()] = b"note"
        rows["kind"] = kinds
    capsys.readouterr()
    rc = main(["replay", str(run_file), "--runs-dir", str(tmp_path / "replays")])
    out, err = capsys.readouterr()
    assert rc == EXIT_BAD_INPUT, (out, err)
    lines = err.strip().splitlines()
    assert lines and all(line.startswith(str(run_file)) for line in lines), err
    assert "/config/text:" in lines[0] and "our_board.yaml" in lines[0] and "not found" in lines[0], err
    assert "recorded before bench kept the files a config names" in lines[0] and "configs/" in lines[0], err


def test_a_sensor_model_named_through_a_symbolic_link_replays(tmp_path: Path):
    """A lab's `models/our_board.yaml` is a symbolic link to the file it means (`real/...`): the
    text is kept under the name the config gives too, so the replay (which holds no links) finds it."""
    import os

    from tests.conftest import run_cli

    run_file, lab = _lab_run(tmp_path)
    (lab / "models" / "real").mkdir()
    shutil.move(lab / "models" / "our_board.yaml", lab / "models" / "real" / "our_board.yaml")
    os.symlink("real/our_board.yaml", lab / "models" / "our_board.yaml")
    r = run_cli("run", "lab_short.yaml", "--config", "lab.yaml", "--runs-dir", str(tmp_path / "linked"), cwd=lab, timeout=300)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    (linked,) = (tmp_path / "linked").glob("*.h5")
    info = json.loads(next(e for e in read_run_summary(linked).events if e.kind == "config_sources").data)
    real = str((lab / "models" / "real" / "our_board.yaml").resolve())
    named = str((lab / "models").resolve() / "our_board.yaml")
    assert info["sources"][real] == info["sources"][named] and "0.0071" in info["sources"][named]
    shutil.rmtree(lab)
    rc, out = _cli(tmp_path, linked)
    assert rc == EXIT_OK and "MATCH" in out, out
