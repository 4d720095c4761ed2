"""A lab's own board frames as data (issue 28, part 5; docs/frame-descriptions.md).

* Ours is one description (drivers/frames/acs_board.yaml): the procedure layer's default board
  signals equal it; the golden tests of docs/acs-board-protocol.md check its bytes.
* Every problem in a description file is located (file:line), through `bench validate --config`.
* The codec is generic: a third format with another sync, a version byte, a 16-bit length, a
  CRC-16/CCITT-FALSE sent little-endian, big-endian fields, a 32-bit counter, the MPU-6000's
  temperature formula and a temperature in kelvin round-trips through any chunking and
  resynchronises after garbage; its simulator and the driver talk in it.
* An Xsens MTi's MTData2 messages as the MTi-300 of a public recording sent them decode through
  the description with MT Manager's values (tests/golden/test_xsens_mtdata2.py).
* configs/frames/xsens_mti.yaml runs end to end from its YAML alone: validate (a step it has no
  command for is refused, located), dry-run, record, replay, diagnose.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import serial
from hypothesis import given, settings, strategies as st

from bench.board_frames import load_frame_description
from bench.clock import VirtualClock
from bench.errors import InputErrors
from bench.procedure.signals import kind_signals
from bench.sim import registry
from drivers.acs_board import AcsBoard
from drivers.board_frames import parse_reply
from drivers.frame_decoder import FrameDecoder
from drivers.frame_schema import builtin_description
from drivers.errors import ProtocolError
from tests.conftest import ROOT, SIM_CONFIG, run_cli

XSENS = ROOT / "configs" / "frames" / "xsens_mti.yaml"

# A lab's board: every header and check choice different from ours. The temperature is the
# MPU-6000's register formula (RM-MPU-6000A-00 rev 4.2, TEMP_OUT: degC = raw/340 + 36.53).
LAB_BOARD = """schema: bench-board-frames/1
name: lab-board-2
byte_order: big
sync: [0x55, 0xAA, 0x7E]
header: [version, type, length16]
version: 2
check: {algorithm: crc16_ccitt_false, from: 3, byte_order: little}
max_payload: 64
data:
  id: 0x20
  fields:
    - {name: counter, type: u4}
    - {name: board_time, type: u4, units: ms}
    - {name: gyro, type: i4, count: 3, scale: 1/65536, units: deg/s}
    - {name: accel, type: i2, count: 3, units: mg}
    - {name: mag, type: i2, count: 3, scale: 0.1, units: uT, byte_order: little}
    - {name: temp, type: i2, scale: 1/340, offset: 36.53, units: degC}
    - {name: temp_accel, type: i2, scale: 0.0625, units: degC, quantity: temperature}
    - {name: temp_mag, type: u2, scale: 0.01, offset: 200, units: K, quantity: temperature}
    - {name: supply, type: u2, scale: 0.001, units: V, sim: 5.0}
    - {name: status, type: u4}
status_bits: {always: 0x1, streaming: 0x100, sensor_power: 0x200, bit_failed: 0x400, saturated: 0x800}
commands:
  identify: {id: 0x40, reply: {id: 0x41, text: [model, serial], separator: ","}}
  start_stream: {id: 0x42, reply: {id: 0x43}, requires: [sensors_on]}
  stop_stream: {id: 0x44, reply: {id: 0x45}}
  set_odr: {id: 0x46, payload: [{name: odr_hz, type: u2}], reply: {id: 0x47}}
  sensor_power: {id: 0x48, payload: [{name: power, type: u1}], reply: {id: 0x49}}
  run_bit: {id: 0x4A, reply: {id: 0x4B, payload: [{name: failed_mask, type: u4}]}, requires: [sensors_on]}
nak:
  id: 0x7F
  payload: [{name: code, type: u1}, {name: command, type: u1}]
  codes: {unknown_command: 0xE1, bad_length: 0xE2, bad_value: 0xE3, not_allowed_in_state: 0xE4, crc_error: 0xE5}
power_up: {odr_hz: 50, sensors_on: false}
"""


@pytest.fixture(scope="module")
def lab_board(tmp_path_factory):
    path = tmp_path_factory.mktemp("frames") / "lab_board_2.yaml"
    path.write_text(LAB_BOARD, encoding="utf-8")
    return load_frame_description(path)


def test_ours_is_a_description_and_the_default_signals_are_its_signals():
    d = builtin_description()
    columns, vectors = d.signal_table()
    ours = kind_signals("acs_board")  # the kind's declared signals (bench/kinds/acs_board)
    assert columns == ours.columns and vectors == ours.vectors
    assert (d.data_frame_len, d.header_len, d.check_at) == (38, 4, 36)  # docs/acs-board-protocol.md "Data frame"
    assert [c[0] for c in d.stream_columns()] == ["counter", "board_time", "gyro", "accel", "mag", "temp", "status"]


# ---- located errors ----------------------------------------------------------------------------
BROKEN = {
    "type: i2, count: 3, at: 10": ("type: i3, count: 3, at: 10", "data.fields[2].type", "expected one of u1"),
    "{name: board_time, type: u4, at: 6,": ("{name: board_time, type: u4, at: 7,", "data.fields[1].at", "end at byte 6"),
    "scale: 2/32768, units: g,": ("scale: 2/32768, units: furlong,", "data.fields[3].units", "specific force in 'furlong'"),
    "name: mag, type: i2, count: 3": ("name: mag, type: i2, count: 2", "data.fields[4].count", "mag has 3 value(s)"),
    "  stop_stream: {id: 0x12,": ("  stop_stream: {id: 0x11,", "commands.stop_stream.id", "also commands.start_stream.id"),
    "scale: 250/32768,": ("scale: 250/0,", "data.fields[2].scale", "a ratio such as 250/32768"),
}


@pytest.mark.parametrize("old", list(BROKEN))
def test_a_bad_description_is_refused_at_its_line(tmp_path, old):
    new, field, message = BROKEN[old]
    text = (ROOT / "drivers" / "frames" / "acs_board.yaml").read_text(encoding="utf-8")
    assert text.count(old) == 1
    bad = tmp_path / "board.yaml"
    bad.write_text(text.replace(old, new), encoding="utf-8")
    line = next(i for i, t in enumerate(bad.read_text().splitlines(), 1) if new in t)
    with pytest.raises(InputErrors) as err:
        load_frame_description(bad)
    e = err.value.errors[0]  # the first problem is the one written there (a wrong count also shifts the fields after it)
    assert e.location.line == line and e.field == field and message in e.message, (e.location, e.field, e.message)


def test_validate_locates_a_problem_in_the_config_named_description(tmp_path):
    bad = tmp_path / "frames.yaml"
    bad.write_text(LAB_BOARD.replace("    - {name: board_time, type: u4, units: ms}\n", ""), encoding="utf-8")
    config = _config(tmp_path, bad, serial="SIM-0001")
    proc = tmp_path / "p.yaml"
    proc.write_text("schema: bench-procedure/1\nname: p\ninstruments: [acs_board]\nsteps:\n  - wait: {duration: 1 s}\n")
    r = run_cli("validate", str(proc), "--config", str(config))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert f"{bad}:11:" in r.stdout + r.stderr and "board_time" in r.stdout + r.stderr, r.stdout + r.stderr


# ---- a lab's format: codec, simulator and driver -----------------------------------------------------
def _rows(d, n: int, rng) -> dict[str, np.ndarray]:
    raw = {}
    for f in d.recorded:
        lo, hi = f.raw_limits if f.integer else (-1e6, 1e6)
        shape = (n,) + f.shape
        raw[f.name] = rng.integers(lo, hi, shape, endpoint=True) if f.integer else rng.uniform(lo, hi, shape)
    raw["counter"] = (np.arange(n) + 2**32 - 3) % 2**32  # wraps: 2^32 - 3 ... 0, 1, ...
    raw["board_time"] = (np.arange(n) * 20 + 2**32 - 50) % 2**32
    return raw


@settings(max_examples=40, deadline=None)
@given(cuts=st.lists(st.integers(0, 53 * 12), max_size=8), garbage=st.binary(max_size=40), seed=st.integers(0, 2**16))
def test_a_lab_format_round_trips_through_any_chunking(lab_board, cuts, garbage, seed):
    d = lab_board
    raw = _rows(d, 12, np.random.default_rng(seed))
    garbage = garbage.replace(b"\x55", b"\x54")  # noise without a sync byte: every byte of it is garbage
    stream = garbage + d.encode_data(raw)
    dec = FrameDecoder(d)
    pieces = [stream[a:b] for a, b in zip([0] + sorted(cuts), sorted(cuts) + [len(stream)])]
    batches = [dec.feed(p) for p in pieces]
    counter = np.concatenate([b.counter for b in batches])
    assert np.array_equal(counter, raw["counter"]) and dec.dropped_frames == 0
    t = np.concatenate([b.board_time_s for b in batches])
    assert np.allclose(np.diff(t), 0.020) and t[0] == pytest.approx((2**32 - 50) * 1e-3)  # unwrapped across 2^32 ms
    gyro = np.concatenate([b.columns["gyro"] for b in batches])
    assert np.array_equal(gyro, raw["gyro"] / 65536.0)
    temp = np.concatenate([b.columns["temp"] for b in batches])
    assert np.allclose(temp, raw["temp"] / 340.0 + 36.53)
    kelvin = np.concatenate([b.columns["temp_mag"] for b in batches])
    assert np.allclose(kelvin, raw["temp_mag"] * 0.01 + 200 - 273.15)  # recorded in degC
    assert np.allclose(np.concatenate([b.columns["accel"] for b in batches]), raw["accel"] * 1e-3)  # mg -> g
    assert dec.garbage_bytes == len(garbage) and dec.crc_errors == 0


def test_a_lab_format_counts_a_corrupted_frame_and_checks_its_version(lab_board):
    d = lab_board
    raw = _rows(d, 3, np.random.default_rng(1))
    good = bytearray(d.encode_data(raw))
    assert len(good) == 3 * 53 and d.data_frame_len == 53
    bad = bytearray(good)
    bad[53 + 20] ^= 0x10  # a bit of the second frame's payload
    b = FrameDecoder(d).feed(bytes(bad))
    assert list(b.counter) == [raw["counter"][0], raw["counter"][2]] and b.crc_errors == 1 and b.garbage_bytes == 53
    assert b.dropped_frames == 1
    other = bytearray(good)
    other[3] = 3  # another version of the format: not a frame of this description
    b = FrameDecoder(d).feed(bytes(other))
    assert list(b.counter) == list(raw["counter"][1:]) and b.crc_errors == 0 and b.garbage_bytes == 53


def test_the_simulator_and_the_driver_speak_a_lab_format(lab_board):
    from bench.model.imu_simple import ImuModelParams, SimpleImuModel
    from bench.sim.acs_board import AcsBoardIdentity, AcsBoardSim
    from bench.sim.world import World, WorldParams

    clock = VirtualClock()
    sim = AcsBoardSim(clock, World(WorldParams()), SimpleImuModel(ImuModelParams(), np.random.default_rng(3)),
                      AcsBoardIdentity(serial="LB-0042"), description=lab_board)
    url = registry.register("lab_board_test", sim)
    try:
        board = AcsBoard(serial.serial_for_url(url, baudrate=115200, timeout=0.5), description=lab_board)
        assert board.identify() == {"model": "ACS-IMU sim MPU-6000+LIS3MDL", "serial": "LB-0042"}  # what its reply carries
        assert board.get_config() == {"odr_hz": 50, "moving_avg_n": 1, "streaming": False, "sensor_power": False,
                                      "baud": 115200, "read_back": False}  # no GET_CONFIG: as commanded
        with pytest.raises(Exception, match="not allowed"):  # NAK 0xE4 -> DeviceFault
            board.start_stream()
        with pytest.raises(ProtocolError, match="no set_moving_avg command"):
            board.set_moving_average(4)
        board.sensor_power(True)
        board.set_odr(200)
        board.start_stream()
        clock.sleep(2.0)
        b = board.poll()
        assert b.counter.size == 400 and b.crc_errors == b.garbage_bytes == b.dropped_frames == 0
        assert np.allclose(b.columns["supply"], 5.0) and np.allclose(b.columns["temp_mag"], b.columns["temp"], atol=0.01)
        assert np.all(b.status == 0x301)  # always | streaming | sensor power
        assert abs(np.linalg.norm(b.columns["accel"].mean(axis=0)) - 1.0) < 0.01  # 1 g at rest, sent in mg
        board.stop_stream()
    finally:
        registry.unregister("lab_board_test")


# ---- the Xsens MTi description -------------------------------------------------------------------
def test_the_xsens_simulator_answers_the_documented_bytes():
    """GoToConfig ``FA FF 30 00 D1`` -> GoToConfigAck ``FA FF 31 00 D0`` and GoToMeasurement
    ``FA FF 10 00 F1`` (X1, X3 in configs/frames/xsens_mti.yaml), written on the raw link."""
    from bench.model.imu_simple import ImuModelParams, SimpleImuModel
    from bench.sim.acs_board import AcsBoardIdentity, AcsBoardSim
    from bench.sim.world import World, WorldParams

    d = load_frame_description(XSENS)
    clock = VirtualClock()
    sim = AcsBoardSim(clock, World(WorldParams()), SimpleImuModel(ImuModelParams(), np.random.default_rng(3)),
                      AcsBoardIdentity(serial="037003F8"), description=d)
    url = registry.register("xsens_test", sim)
    try:
        port = serial.serial_for_url(url, baudrate=115200, timeout=0.5)
        port.write(bytes.fromhex("FA FF 30 00 D1"))
        assert port.read(5) == bytes.fromhex("FA FF 31 00 D0")
        port.write(bytes.fromhex("FA FF 00 00 01"))  # ReqDID
        assert port.read(9) == bytes.fromhex("FA FF 01 04 03 70 03 F8") + bytes([(-(0xFF + 0x01 + 0x04 + 0x03 + 0x70 + 0x03 + 0xF8)) & 0xFF])
        port.write(bytes.fromhex("FA FF 10 00 F1"))
        ack = port.read(5)
        assert ack == bytes.fromhex("FA FF 11 00 F0")
        clock.sleep(0.1)
        frames = port.read(10 * 61)
        assert len(frames) == 10 * 61 and frames[:4] == bytes.fromhex("FA FF 36 38")
        assert frames[4:9] == bytes.fromhex("10 20 02 00 00")  # PacketCounter 0 first
        assert sum(frames[1:61]) % 256 == 0
        port.write(bytes.fromhex("FA FF 99 00 68"))  # a MID the MTi does not have: Error 0x04 (invalid message)
        assert bytes.fromhex("FA FF 42 01 04 BA") in port.read(200)
    finally:
        registry.unregister("xsens_test")


def _config(tmp_path: Path, frames: Path, serial: str = "037003F8", extra: str = "") -> Path:
    text = SIM_CONFIG.read_text(encoding="utf-8")
    text = text.replace("sensor_model: sensors/", f"sensor_model: {SIM_CONFIG.parent}/sensors/")
    text = text.replace("  acs_board:\n    driver: acs_board\n", f"  acs_board:\n    driver: acs_board\n    frames: {frames}\n{extra}", 1)
    text = text.replace("      serial: SIM-0001\n", f"      serial: {serial}\n", 1)
    path = tmp_path / "lab.yaml"
    path.write_text(text, encoding="utf-8")
    return path


XSENS_PROCEDURE = """schema: bench-procedure/1
name: xsens_ramp
title: An Xsens MTi through a short chamber ramp (tests/test_frame_descriptions.py)
instruments: [acs_board, tvac]
interlocks:
  - {stall: acs_board, max_gap: 2 s}
steps:
  - configure: {instrument: acs_board, odr: 100 Hz}
  - set_temperature: {instrument: tvac, set_point: 30 degC, ramp: 1 degC/min, name: ramp up}
  - record: {instrument: acs_board, duration: 6 min, window: ramp}
  - check: {name: die temperature rose, signal: acs_board.temp, statistic: slope, window: ramp, min: 0 degC/s}
  - check: {name: gravity, signal: acs_board.accel.z, statistic: mean, window: ramp, min: 0.98 g_n, max: 1.02 g_n}
  - set_temperature: {instrument: tvac, set_point: 20 degC, name: back to ambient}
"""


def test_an_xsens_mti_runs_end_to_end_from_its_description(tmp_path):
    from bench.record import read_run_summary

    config = _config(tmp_path, XSENS)
    proc = tmp_path / "xsens_ramp.yaml"
    proc.write_text(XSENS_PROCEDURE, encoding="utf-8")
    power = tmp_path / "power.yaml"  # the MTi has no sensor-power command: refused before anything moves
    power.write_text(XSENS_PROCEDURE.replace("  - configure:", "  - power: {instrument: acs_board, on: true}\n  - configure:"))
    r = run_cli("validate", str(power), "--config", str(config))
    assert r.returncode == 2 and f"{power}:8:" in r.stdout + r.stderr and "no sensor_power command" in r.stdout + r.stderr, r.stdout + r.stderr

    runs = tmp_path / "runs"
    r = run_cli("run", str(proc), "--config", str(config), "--sim", "--runs-dir", str(runs), timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    (run,) = runs.glob("*.h5")
    summary = read_run_summary(run)
    (board,) = [s for s in summary.streams if s.key == "acs_board"]
    assert board.rows == 6 * 60 * 100
    assert board.shapes == {"counter": (), "board_time": (), "accel": (3,), "gyro": (3,), "temp": (), "status": ()}
    assert board.columns["accel"] == "g" and board.columns["gyro"] == "deg/s" and board.columns["temp"] == "degC"
    ident = summary.instruments["acs_board"]
    assert ident["serial"] == "037003F8" and ident["driver"] == "acs_board"
    assert [s.outcome for s in summary.steps if s.type == "check"] == ["passed", "passed"]

    r = run_cli("replay", str(run), "--runs-dir", str(tmp_path / "replays"), timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "board samples (acs_board) checked against a re-simulation of the dry-run" in r.stdout + r.stderr

    r = run_cli("diagnose", str(run), "--json", timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    doc = json.loads(r.stdout)
    assert set(doc["axes"]) == {"x", "y", "z"} and all(v["rms_baseline"] > 0 for v in doc["axes"].values())


def test_an_identity_the_description_sends_as_a_number_needs_a_numeric_serial(tmp_path):
    config = _config(tmp_path, XSENS, serial="SIM-0001")
    proc = tmp_path / "p.yaml"
    proc.write_text("schema: bench-procedure/1\nname: p\ninstruments: [acs_board]\nsteps:\n  - wait: {duration: 1 s}\n")
    r = run_cli("validate", str(proc), "--config", str(config))
    assert r.returncode == 2 and "sends the serial as a u4 number" in r.stdout + r.stderr, r.stdout + r.stderr


def test_reply_parsing_follows_the_description(lab_board):
    assert parse_reply(lab_board, "identify", b"IMU-9,SN7") == {"model": "IMU-9", "serial": "SN7"}
    assert parse_reply(lab_board, "run_bit", bytes([0, 0, 1, 2])) == {"failed_mask": 0x0102}  # big-endian u4
    with pytest.raises(ProtocolError, match="payload must be 4 bytes"):
        parse_reply(lab_board, "run_bit", b"\x00\x01")
