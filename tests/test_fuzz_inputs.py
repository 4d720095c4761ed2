"""Fuzzing of every input path: bad input is a typed, located error, never a traceback.

1. Instrument answers: the ACS frame decoder (corrupted, truncated, inserted, concatenated frames;
   the board-side decoder too), the board driver's reply handling, the CAN serial tunnel's frame
   reassembly and URLs, the TPG 261 line parser, the thermocouple logger's SCPI answers, the
   stepper bench's status lines. Only the documented error types (``InstrumentError`` family).
2. YAML procedures and lab configs: random documents, structured and textual mutations of the
   shipped files, non-UTF-8 bytes, tags, aliases. Loads, or ``InputError`` naming the file.
3. Measured-data CSV: round trips, located errors (file:line) for every kind of damage.
4. Run files: truncated and overwritten copies of tests/sessions/*.h5 read in a worker process
   (HDF5 may hang or crash on a damaged file: a hang or a crash fails the test, it does not take
   pytest down), zero-length, foreign and future-format files.
5. The CLI end to end: exit code 2, no traceback.
6. Crafted and damaged run files (issue 21): a small real run file cut at every HDF5 structure of
   its first 64 KiB (every byte: marked slow) and read as the replay reads it, the CLI on cuts
   (replay, inspect, report, diagnose, calibrate, catalog rebuild) with a time limit; FIFOs and
   devices named as run files; crafted paths and names replayed under an audit hook (nothing read
   or written outside the replay's directories); a recorded value changed in the file diverges.

``docs/reliability.md`` ("Bad input") lists what is fuzzed and the bugs these tests found.
"""

from __future__ import annotations

import json
import math
import os
import re
import select
import shutil
import subprocess
import sys
import tempfile
import threading
import uuid
from pathlib import Path

import can
import h5py
import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from bench.analysis.dataset import COLUMNS, dataset_from_csv, dataset_from_run, load_dataset
from bench.config import load_config
from bench.csvsrc import read_numeric_csv
from bench.errors import DeviceFault, InputError, InputErrors, InstrumentError, InstrumentTimeout, ProtocolError
from bench.procedure import load_procedure, parse_procedure
from bench.record.reader import read_run_summary
from bench.record.writer import FORMAT_VERSION
from bench.yamlsrc import load_yaml
from drivers import acs_protocol as proto
from drivers.acs_board import AcsBoard
from drivers.can_serial import CanSerialPort, parse_can_serial_url
from drivers.stepper_bench import StepperBench
from drivers.thermocouple_reader import ThermocoupleReader
from drivers.tpg261 import Tpg261, parse_pr_reply
from tests.cli_output import one_error_line
from tests.conftest import ROOT
from tests.test_acs_protocol import SYNC, frame_bytes

_BASE = settings(deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture,
                                                       HealthCheck.data_too_large, HealthCheck.filter_too_much])


def fuzz(examples: int) -> settings:
    """Hypothesis settings of this file: no deadline (a loaded machine), ``examples`` examples."""
    return settings(_BASE, max_examples=examples)
SESSIONS = sorted((ROOT / "tests" / "sessions").glob("*.h5"))
PROCEDURES = sorted((ROOT / "procedures").glob("*.yaml"))
CONFIGS = sorted((ROOT / "configs").glob("*.yaml"))


# =================================================================================================
# 1. instrument answers
# =================================================================================================
@st.composite
def board_frames(draw, max_frames: int = 12) -> list[bytes]:
    """Good frames as the board sends them: data frames with consecutive counters, and replies."""
    n = draw(st.integers(1, max_frames))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    c0 = int(rng.integers(0, 65536))
    frames = []
    for i in range(n):
        kind = draw(st.sampled_from(["data", "data", "data", "ack", "nak"]))
        if kind == "data":
            v = lambda: rng.integers(-32768, 32768, (1, 3))  # noqa: E731
            frames.append(proto.encode_data_frames(np.array([(c0 + i) % 65536]), rng.integers(0, 2**32, 1), v(), v(), v(), v(),
                                                   rng.integers(0, 65536, 1)))
        elif kind == "ack":
            cmd = draw(st.sampled_from(proto.COMMANDS))
            frames.append(proto.encode_frame(proto.reply_type(cmd), draw(st.binary(max_size=proto.MAX_PAYLOAD))))
        else:
            frames.append(proto.encode_frame(proto.FrameType.NAK, bytes([draw(st.integers(0, 255)), draw(st.integers(0, 255))])))
    return frames


_DAMAGE = st.sampled_from(["intact", "intact", "flip", "delete", "insert", "truncate"])


def _damage(frame: bytes, how: str, data: st.DataObject) -> bytes:
    b = bytearray(frame)
    if how == "flip":
        i = data.draw(st.integers(0, len(b) - 1))
        b[i] ^= data.draw(st.integers(1, 255))
    elif how == "delete":
        i = data.draw(st.integers(0, len(b) - 1))
        del b[i:i + data.draw(st.integers(1, 8))]
    elif how == "insert":
        i = data.draw(st.integers(1, len(b) - 1))
        b[i:i] = data.draw(st.binary(min_size=1, max_size=8))
    elif how == "truncate":
        b = b[:data.draw(st.integers(0, len(b) - 1))]
    return bytes(b)


def _reencoded(batch: proto.DecodedBatch) -> list[bytes]:
    """The data frames of ``batch`` encoded again from the decoded physical values (with a correct CRC)."""
    if batch.counter.size == 0:
        return []
    t_us = np.rint(batch.board_time_s / proto.BOARD_TIME_S_PER_LSB).astype(np.int64) % 2**32
    raw = [np.rint(a / s).astype(np.int64) for a, s in ((batch.gyro_dps, proto.GYRO_DPS_PER_LSB), (batch.accel_g, proto.ACCEL_G_PER_LSB),
                                                         (batch.mag_ut, proto.MAG_UT_PER_LSB), (batch.temp_degc, proto.TEMP_DEGC_PER_LSB))]
    out = proto.encode_data_frames(batch.counter, t_us, *raw, batch.status)
    return [out[i:i + proto.DATA_FRAME_LEN] for i in range(0, len(out), proto.DATA_FRAME_LEN)]


@fuzz(120)
@given(frames=board_frames(), board_side=st.booleans(), data=st.data())
def test_decoder_on_damaged_streams_returns_only_crc_valid_frames_and_resynchronises(frames, board_side, data):
    """Frames flipped, cut short, with bytes deleted or inserted, noise between them, fed in any
    chunking: the decoder never raises, every frame it returns is a CRC-valid frame of the input,
    every undamaged frame is decoded, and every byte is accounted for (frame, garbage or held)."""
    stream, intact = b"", []
    for frame in frames:
        if data.draw(st.booleans()):
            stream += data.draw(st.binary(max_size=40))  # noise, sync words included
        how = data.draw(_DAMAGE)
        if how == "intact":
            intact.append(frame)
        stream += _damage(frame, how, data)
    stream += bytes(2 + 4 + proto.MAX_PAYLOAD + 2)  # zeros: every held candidate becomes decidable
    dec = proto.FrameDecoder(accept_unknown_types=board_side)
    cuts = sorted(set(data.draw(st.lists(st.integers(0, len(stream)), max_size=8))) | {0, len(stream)})
    decoded_data, replies, accepted, counters = [], [], 0, []
    for a, b in zip(cuts[:-1], cuts[1:]):
        held = dec.pending_bytes
        batch = dec.feed(stream[a:b])
        assert batch.frames_ok == batch.counter.size + len(batch.replies)
        # this feed's bytes and those held from the last: in a good frame, garbage, or held again
        assert frame_bytes(batch) + batch.garbage_bytes + dec.pending_bytes == held + (b - a)
        assert batch.crc_errors <= stream[a - held:b].count(SYNC)  # each CRC error starts at a sync word
        decoded_data += _reencoded(batch)
        replies += batch.replies
        accepted += frame_bytes(batch)
        counters += batch.counter.tolist()
    for frame in decoded_data + [proto.encode_frame(t, p) for t, p in replies]:
        assert frame in stream, f"decoder returned a frame that is not in its input: {frame.hex()}"
    assert dec.pending_bytes == 0
    assert dec.garbage_bytes + accepted == len(stream)
    # dropped frames: the counter gaps (modulo 65536) between the data frames returned, across feeds
    assert dec.dropped_frames == sum((c1 - c0 - 1) % 65536 for c0, c1 in zip(counters, counters[1:]) if c1 != c0)
    returned = decoded_data + [proto.encode_frame(t, p) for t, p in replies]
    missing = [f.hex() for f in intact if f not in returned]
    assert not missing, f"undamaged frames not decoded (no resynchronisation): {missing}"


@fuzz(60)
@given(frames=board_frames(max_frames=20), cuts=st.lists(st.integers(0, 4000), max_size=12))
def test_concatenated_data_and_reply_frames_decode_the_same_in_any_chunking(frames, cuts):
    data = b"".join(frames)
    whole = proto.FrameDecoder().feed(data)
    dec = proto.FrameDecoder()
    bounds = sorted({0, len(data), *[c % (len(data) + 1) for c in cuts]})
    parts = [dec.feed(data[a:b]) for a, b in zip(bounds[:-1], bounds[1:])]
    assert [r for p in parts for r in p.replies] == whole.replies
    assert np.array_equal(np.concatenate([p.counter for p in parts]), whole.counter)
    assert np.array_equal(np.concatenate([p.gyro_dps for p in parts]), whole.gyro_dps)
    assert whole.frames_ok == len(frames) and whole.garbage_bytes == 0 and dec.garbage_bytes == 0


@fuzz(80)
@given(st.binary(max_size=200))
def test_reply_payload_parsers_raise_only_protocol_error(payload):
    for parse, size in ((proto.parse_nak, 2), (proto.parse_bit, 2), (proto.parse_config, 9)):
        if len(payload) == size:
            parse(payload)
        else:
            with pytest.raises(ProtocolError, match="acs_board: .* payload must be"):
                parse(payload)
    ident = proto.parse_identity(payload)
    assert set(ident) == {"vendor", "model", "serial", "firmware"} and all(isinstance(v, str) for v in ident.values())


class ScriptedPort:
    """A serial-port double: every write is answered at once with ``answer(written bytes)``;
    a read with nothing buffered returns b"" as a real port does after its timeout."""

    def __init__(self, answer, baudrate: int = 115200):
        self.answer = answer
        self.baudrate = baudrate
        self.timeout = 0.0
        self.rx = bytearray()
        self.written: list[bytes] = []

    def write(self, data) -> int:
        self.written.append(bytes(data))
        self.rx += self.answer(bytes(data))
        return len(data)

    @property
    def in_waiting(self) -> int:
        return len(self.rx)

    def read(self, size: int = 1) -> bytes:
        out = bytes(self.rx[:size])
        del self.rx[:size]
        return out

    def reset_input_buffer(self) -> None:
        self.rx.clear()

    def close(self) -> None:
        pass


@st.composite
def board_answers(draw) -> bytes:
    """What a misbehaving board may answer: noise, ACK frames of any command with any payload,
    NAKs of any length, data frames."""
    pieces = []
    for _ in range(draw(st.integers(0, 4))):
        kind = draw(st.sampled_from(["noise", "ack", "nak", "data"]))
        if kind == "noise":
            pieces.append(draw(st.binary(max_size=30)))
        elif kind == "ack":
            pieces.append(proto.encode_frame(proto.reply_type(draw(st.sampled_from(proto.COMMANDS))), draw(st.binary(max_size=12))))
        elif kind == "nak":
            cmd = draw(st.sampled_from(proto.COMMANDS))
            pieces.append(proto.encode_frame(proto.FrameType.NAK, bytes([cmd]) + draw(st.binary(max_size=3))))
        else:
            z = np.zeros((1, 3))
            pieces.append(proto.encode_data_frames(np.array([draw(st.integers(0, 65535))]), np.array([0]), z, z, z, z, np.array([0])))
    return b"".join(pieces)


@fuzz(80)
@given(answer=board_answers(), command=st.sampled_from(["identify", "get_config", "run_bit", "start_stream", "sensor_power"]))
def test_board_driver_turns_any_answer_into_a_result_or_an_instrument_error(answer, command):
    board = AcsBoard(ScriptedPort(lambda _: answer), timeout_s=0.01, retries=0)
    call = {"identify": board.identify, "get_config": board.get_config, "run_bit": board.run_bit,
            "start_stream": board.start_stream, "sensor_power": lambda: board.sensor_power(True)}[command]
    try:
        result = call()
    except InstrumentError:
        return
    if command == "get_config":
        assert set(result) == {"odr_hz", "moving_avg_n", "streaming", "sensor_power", "baud"}
    elif command == "run_bit":
        assert 0 <= result <= 0xFFFF
    board.poll()  # data frames that came with the answer are kept and decodable


def test_nak_with_a_short_payload_is_a_protocol_error_not_a_value_error():
    """Found by fuzzing: a NAK naming the command but one byte long raised ValueError."""
    nak = proto.encode_frame(proto.FrameType.NAK, bytes([proto.FrameType.RUN_BIT]))
    board = AcsBoard(ScriptedPort(lambda _: nak), timeout_s=0.01, retries=0)
    with pytest.raises(ProtocolError, match="NAK payload must be 2 bytes, got 1"):
        board.run_bit()
    short_config = proto.encode_frame(proto.reply_type(proto.FrameType.GET_CONFIG), b"\x01\x02")
    board = AcsBoard(ScriptedPort(lambda _: short_config), timeout_s=0.01, retries=0)
    with pytest.raises(ProtocolError, match="GET_CONFIG payload must be 9 bytes, got 2"):
        board.get_config()


# ---- CAN serial tunnel ---------------------------------------------------------------------------
@fuzz(150)
@given(st.one_of(
    st.text(max_size=60),
    st.builds(lambda i, c, q: f"can://{i}/{c}?{q}", st.sampled_from(["virtual", "slcan", "socketcan", "vcan", ""]),
              st.text(max_size=12), st.text(alphabet="nodebitrate=&0123456789-x%;?", max_size=30)),
))
def test_can_serial_url_parser_raises_only_instrument_error(url):
    try:
        u, node, bitrate = parse_can_serial_url(url)
    except InstrumentError as exc:
        assert repr(url) in str(exc) or url in str(exc)
        return
    assert u.interface in ("virtual", "slcan", "socketcan") and u.channel
    assert 1 <= node <= 127 and bitrate > 0


@pytest.fixture(scope="module")
def can_rig():
    channel = f"fuzz-{uuid.uuid4().hex}"
    port = CanSerialPort(can.Bus(interface="virtual", channel=channel, receive_own_messages=False), 42, timeout=2.0)
    sender = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    yield port, sender
    port.close()
    sender.shutdown()


_CAN_KINDS = st.sampled_from(["stream", "stream", "other_id", "extended", "remote", "error", "marker"])


@fuzz(40)
@given(frames=st.lists(st.tuples(_CAN_KINDS, st.binary(min_size=1, max_size=8)), max_size=12))
def test_can_tunnel_keeps_exactly_the_stream_bytes_of_the_board_id_in_order(can_rig, frames):
    """Error frames, remote frames, other ids, extended ids and sync markers carry no stream bytes."""
    port, sender = can_rig
    rx = port.rx_id
    expected = b""
    errors_before = port.error_frames
    for kind, payload in frames:
        if kind == "stream":
            msg = can.Message(arbitration_id=rx, is_extended_id=False, data=payload)
            expected += payload
        elif kind == "other_id":
            msg = can.Message(arbitration_id=rx + 1, is_extended_id=False, data=payload)
        elif kind == "extended":
            msg = can.Message(arbitration_id=rx, is_extended_id=True, data=payload)
        elif kind == "remote":
            msg = can.Message(arbitration_id=rx, is_extended_id=False, is_remote_frame=True, dlc=len(payload))
        elif kind == "error":
            msg = can.Message(is_error_frame=True, data=payload)
        else:
            msg = can.Message(arbitration_id=rx, is_extended_id=False, data=b"")
        sender.send(msg)
    sender.send(can.Message(arbitration_id=rx, is_extended_id=False, data=b"\x7e"))  # end mark
    assert port.read(len(expected) + 1) == expected + b"\x7e"
    assert port.in_waiting == 0
    assert port.error_frames - errors_before == sum(k == "error" for k, _ in frames)


# ---- TPG 261, thermocouple logger, stepper bench (line protocols) ---------------------------------
def _lines(alphabet: str, max_size: int = 40) -> st.SearchStrategy[bytes]:
    return st.one_of(st.binary(max_size=max_size), st.text(alphabet=alphabet, max_size=max_size).map(lambda s: s.encode("utf-8")))


@fuzz(150)
@given(_lines("0123456789,.E+- \t\r\x06\x15x"))
def test_tpg_pressure_line_parser_raises_only_protocol_error(raw):
    try:
        status, value = parse_pr_reply(raw)
    except ProtocolError as exc:
        assert str(exc).startswith("pressure gauge: ")
        return
    assert 0 <= status <= 9 and math.isfinite(value)


@fuzz(100)
@given(status=st.integers(0, 9), value=st.floats(1e-99, 9.9e99) | st.floats(-9.9e99, -1e-99))
def test_tpg_pressure_line_round_trips(status, value):
    text = f"{status},{value:.4E}"
    assume(re.search(r"E[+-]\d\d$", text))
    assert parse_pr_reply(text.encode() + b"\r\n") == (status, float(f"{value:.4E}"))


def _tpg_answering(answer: bytes) -> ScriptedPort:
    def reply(data: bytes) -> bytes:
        if data == b"\x05":  # ENQ: the data line
            return answer + b"\r\n"
        return b"\x06\r\n" if data.endswith(b"\r\n") else b""  # ACK every mnemonic
    return ScriptedPort(reply, baudrate=9600)


@fuzz(80)
@given(_lines("0123456789,.E+- \r\n\x06\x15"))
def test_tpg_driver_turns_any_answer_into_a_reading_or_an_instrument_error(answer):
    gauge = Tpg261(_tpg_answering(answer), timeout_s=0.01)
    try:
        reading = gauge.read_pressure()
    except InstrumentError:
        return
    assert reading.status in (0, 1) and math.isfinite(reading.torr)


def _scpi_answering(answers: dict[str, bytes]) -> ScriptedPort:
    def reply(data: bytes) -> bytes:
        line = data.decode("ascii").strip()
        for prefix, answer in answers.items():
            if line.startswith(prefix):
                return answer + b"\n"
        return b""
    return ScriptedPort(reply, baudrate=57600)


_READING = st.one_of(st.floats(-270.0, 1372.0).map(lambda v: f"{v:+.8E}"), st.sampled_from(["+9.90000000E+37", "-9.90000000E+37"]))
"""A reading as the 34970A sends it, SD.DDDDDDDDESDD over type K's range (degC), or the overload of either
sign (docs/golden/keysight-34970a.md K6, K7)."""
_IDN = st.lists(st.text(st.characters(min_codepoint=0x21, max_codepoint=0x7E, exclude_characters=","), min_size=1, max_size=12),
                min_size=4, max_size=4)
"""Four ``*IDN?`` fields (vendor, model, serial, firmware): printable ASCII without commas."""
_SCPI_ERROR = st.tuples(st.integers(-440, -100), st.text(st.characters(min_codepoint=0x20, max_codepoint=0x7E, exclude_characters='"'), max_size=30))


def _reader_answering(answer: bytes, query: str) -> ThermocoupleReader:
    """A reader configured for channels 101 and 102 (no error queued) whose ``query`` is answered with ``answer``."""
    scpi = {"read": "READ?", "rjun": "SENS:TEMP:TRAN:TC:RJUN?", "identify": "*IDN?", "errors": "SYST:ERR?"}[query]
    answers = {"SYST:ERR?": b'+0,"No error"', scpi: answer}
    reader = ThermocoupleReader(_scpi_answering(answers), timeout_s=0.01)
    if query != "errors":
        reader.configure([101, 102])
    return reader


@fuzz(60)
@given(readings=st.lists(_READING, min_size=2, max_size=2), rjun=st.floats(-55.0, 85.0), idn=_IDN, error=st.one_of(st.none(), _SCPI_ERROR))
def test_thermocouple_reader_gives_the_values_of_every_well_formed_answer(readings, rjun, idn, error):
    """Well-formed answers (K1-K9 of the golden table, with drawn values) are read, never refused."""
    scan = _reader_answering(",".join(readings).encode() + b"\r", "read").read()
    for ch, text in zip((101, 102), readings):
        if abs(float(text)) > 9e37:
            assert scan.temps_c[ch] is None and ch in scan.open_channels
        else:
            assert scan.temps_c[ch] == float(text) and ch not in scan.open_channels
    assert _reader_answering(f"{rjun:+.8E}\r".encode(), "rjun").reference_junction_c(101) == pytest.approx(rjun, rel=1e-8)
    assert _reader_answering(",".join(idn).encode(), "identify").identify() == dict(zip(("vendor", "model", "serial", "firmware"), idn))
    if error is None:
        _reader_answering(b'+0,"No error"\r', "errors").check_errors()
    else:
        queued = f'{error[0]:+d},"{error[1]}"'
        with pytest.raises(DeviceFault) as exc:  # the queue holds the error, then says it is empty
            _reader_answering(queued.encode() + b'\n+0,"No error"', "errors").check_errors()
        assert queued in str(exc.value) and "No error" not in str(exc.value)


def _first_line(answer: bytes) -> str | None:
    """The first non-blank line of ``answer`` (an answer is read up to LF, as ASCII, surrounding white
    space stripped), or None if it has none (then the reader waits for one and times out)."""
    lines = (raw.decode("ascii", "replace").strip() for raw in (answer + b"\n").split(b"\n"))
    return next((line for line in lines if line), None)


@fuzz(100)
@given(answer=_lines("0123456789,.E+-naif \r\x00_", max_size=60), query=st.sampled_from(["read", "rjun", "identify", "errors"]))
def test_thermocouple_reader_turns_any_answer_into_its_values_or_an_instrument_error(answer, query):
    """Whatever the logger answers: the values of the answer's first line, or an ``InstrumentError``
    (a timeout exactly when no line came; the queued error quoted when ``SYST:ERR?`` gives one)."""
    line = _first_line(answer)
    reader = _reader_answering(answer, query)
    call = {"read": reader.read, "rjun": lambda: reader.reference_junction_c(101), "identify": reader.identify,
            "errors": reader.check_errors}[query]
    try:
        result = call()
    except InstrumentTimeout:
        assert line is None
        return
    except DeviceFault as exc:
        assert query == "errors" and line is not None and not line.startswith(("+0", "0,")) and line in str(exc)
        return
    except InstrumentError:
        assert line is not None and query != "errors"  # an answer the reader refuses (ProtocolError)
        return
    assert line is not None
    if query == "read":
        values = [float(v) for v in line.split(",")]
        assert len(values) == 2
        for ch, v in zip((101, 102), values):
            assert result.temps_c[ch] == (None if not math.isfinite(v) or abs(v) >= 9e37 else v)
    elif query == "rjun":
        assert result == float(line) and math.isfinite(result)
    elif query == "identify":
        assert list(result.values()) == [p.strip() for p in line.split(",")]
    else:
        assert result is None and line.startswith(("+0", "0,"))


def test_thermocouple_reference_junction_garbage_is_a_protocol_error():
    """Found by fuzzing: a garbled RJUN? answer raised ValueError from float()."""
    reader = ThermocoupleReader(_scpi_answering({"SENS:TEMP:TRAN:TC:RJUN?": b"+2.1E+0\x00"}), timeout_s=0.01)
    with pytest.raises(ProtocolError, match="RJUN"):
        reader.reference_junction_c(101)


_STATUS_PIECES = st.one_of(
    st.builds(lambda s, p, f, extra: f"<{s}|MPos:{p},0.000,0.000|FS:{f},0{extra}>",
              st.sampled_from(["Idle", "Jog", "Hold:0", "Hold:1", "", "Ru n", "Idlé", "Door:9x"]),
              st.sampled_from(["123.456", "1.2.3", "...", ".", "-", "1e5", "9" * 5000, "0", "360.000", "-0.000"]),
              st.sampled_from(["0", "60", "", "x", "9" * 5000, "1.5"]),
              st.sampled_from(["", "|Pn:PXYZRHS", "|WCO:0.000,0.000,0.000", "|Ov:100,100,100", "|Zz:?", "|:", "|Bf:15"])),
    st.text(max_size=40),
)


@fuzz(100)
@given(line=_STATUS_PIECES)
def test_stepper_status_answer_gives_a_status_or_an_instrument_error(line):
    def reply(data: bytes) -> bytes:
        return line.encode("utf-8", "replace").replace(b"\n", b" ") + b"\r\n" if data == b"?" else b"ok\r\n"
    bench = StepperBench(ScriptedPort(reply), timeout_s=0.01)
    try:
        s = bench.status()
    except InstrumentError:
        return
    assert s["state"] in ("Idle", "Jog", "Hold") and math.isfinite(s["angle_deg"]) and math.isfinite(s["rate_dps"])


def test_stepper_status_with_a_malformed_angle_is_a_protocol_error():
    """Found by fuzzing (the old bench protocol): ``Pos:1.2.3`` matched the status pattern and
    float() raised ValueError; GRBL's ``MPos:`` is parsed field by field now."""
    bench = StepperBench(ScriptedPort(lambda _: b"<Idle|MPos:1.2.3,0.000,0.000|FS:0,0>\r\n"), timeout_s=0.01)
    with pytest.raises(ProtocolError, match="malformed position"):
        bench.status()


# =================================================================================================
# 2. YAML procedures and configs
# =================================================================================================
@pytest.fixture(scope="module")
def tree(tmp_path_factory) -> Path:
    """A copy of procedures/ and configs/ (relative references between them keep working)."""
    root = tmp_path_factory.mktemp("tree")
    shutil.copytree(ROOT / "procedures", root / "procedures")
    shutil.copytree(ROOT / "configs", root / "configs")
    return root


def _load(kind: str, path: Path):
    return load_procedure(path) if kind == "procedure" else load_config(path)


def _check_loads_or_names_file(kind: str, path: Path) -> None:
    """Loads, or raises InputError (only) whose every line is located in the file or its references."""
    try:
        _load(kind, path)
    except InputError as exc:
        assert path.name in str(exc), str(exc)
        errors = exc.errors if isinstance(exc, InputErrors) else [exc]
        for e in errors:
            line = e.one_line()
            assert "\n" not in line and e.location is not None, line


_SCALARS = st.one_of(
    st.none(), st.booleans(), st.integers(), st.floats(), st.text(max_size=15),
    st.sampled_from(["10 s", "30 min", "-29 degC", "1e-5 Torr", "100 Hz", "5 parsec", "$x", "${x}", "acs_board", "tvac",
                     "rate_table", "bench-procedure/1", "bench-config/1", "sim", "uart", "can", "K", "sim.yaml", "../procedures/x.yaml"]),
)
_KEYS = st.one_of(st.sampled_from([
    "schema", "name", "title", "instruments", "steps", "parameters", "limits", "interlocks", "mode", "world", "recorder",
    "driver", "port", "sim", "backend", "timeout", "baudrate", "channels", "wait", "record", "configure", "power", "repeat",
    "for_each", "call", "rate_steps", "duration", "instrument", "values", "var", "count", "procedure", "args", "latitude",
    "steps_per_deg", "max_rate", "acceleration", "sensor_model", "eccentricity", "signal", "max", "min", "stall", "max_gap",
    "requires", "unit", "station", "serial", "firmware", "calibration_due"]),
    st.text(max_size=8))
_VALUES = st.recursive(_SCALARS, lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(_KEYS, inner, max_size=4)),
                       max_leaves=25)


def _dump(doc) -> str:
    return yaml.safe_dump(doc, allow_unicode=True, sort_keys=False)


@fuzz(80)
@given(kind=st.sampled_from(["procedure", "config"]), doc=st.one_of(_VALUES, st.dictionaries(_KEYS, _VALUES, max_size=6)))
def test_random_yaml_documents_load_or_name_the_file(tree, kind, doc):
    path = tree / ("procedures" if kind == "procedure" else "configs") / "random_doc.yaml"
    path.write_text(_dump(doc), encoding="utf-8")
    _check_loads_or_names_file(kind, path)


def _paths(node, prefix=()):
    """Every (path, value) in a plain YAML tree."""
    yield prefix, node
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _paths(v, prefix + (i,))


@fuzz(120)
@given(source=st.sampled_from(PROCEDURES + CONFIGS), data=st.data())
def test_structured_mutations_of_shipped_files_load_or_name_the_file(tree, source, data):
    """Replace a random subtree of a shipped procedure or config with a random value, delete a key
    or add one: the document keeps most of its structure, so the checks run deep."""
    kind = "procedure" if source.parent.name == "procedures" else "config"
    doc = load_yaml(source).root.plain()  # keys as written ("on" stays a name, not a YAML 1.1 boolean)
    for _ in range(data.draw(st.integers(1, 3))):
        paths = [p for p, _ in _paths(doc) if p]
        target = data.draw(st.sampled_from(paths))
        parent = doc
        for k in target[:-1]:
            parent = parent[k]
        action = data.draw(st.sampled_from(["replace", "replace", "delete", "add"]))
        if action == "replace":
            parent[target[-1]] = data.draw(_VALUES)
        elif action == "delete":
            del parent[target[-1]]
        elif isinstance(parent, dict):
            parent[data.draw(_KEYS)] = data.draw(_VALUES)
        else:
            parent.append(data.draw(_VALUES))
    path = source.parent.relative_to(ROOT)
    fuzzed = tree / path / f"mutated_{source.name}"
    fuzzed.write_text(_dump(doc), encoding="utf-8")
    _check_loads_or_names_file(kind, fuzzed)


_GARBAGE_TEXT = st.text(alphabet=st.sampled_from(list(":-[]{}&*!|>'\"%@`#,?\t\n \\") + ["a", "1", "\x00", "\x85", "\u2028", "\ufeff"]),
                        min_size=1, max_size=12)
_TAGS = ["!!python/object/apply:os.system ", "!!python/name:os.system ", "!!python/object/new:os.system ", "!!binary ",
         "!custom ", "!!set ", "!!omap ", "!!int ", "!!float ", "!!timestamp ", "&a ", "*a ", "<<: "]
_TYPE_CHANGES = ["[1, 2]", "{a: 1}", "42", "true", "null", "'text'", "-1e999", ".nan", "0x1F", "2001-01-01", "9" * 400, "[]", "{}"]


def _mutate_text(raw: bytes, data: st.DataObject) -> bytes:
    """Delete a line, change a value's type, insert garbage, a tag or non-UTF-8 bytes, indent a
    line, truncate at a random byte (once or twice)."""
    for _ in range(data.draw(st.integers(1, 2))):
        lines = raw.split(b"\n")
        i = data.draw(st.integers(0, len(lines) - 1))
        at = data.draw(st.integers(0, len(raw)))
        how = data.draw(st.sampled_from(["delete_line", "type", "garbage", "tag", "non_utf8", "truncate", "indent"]))
        if how == "delete_line":
            del lines[i]
        elif how == "type":
            cut = lines[i].find(b": ")
            if cut >= 0:
                lines[i] = lines[i][:cut + 2] + data.draw(st.sampled_from(_TYPE_CHANGES)).encode()
        elif how == "tag":
            cut = lines[i].find(b": ")
            tag = data.draw(st.sampled_from(_TAGS)).encode()
            lines[i] = lines[i][:cut + 2] + tag + lines[i][cut + 2:] if cut >= 0 else tag + lines[i]
        elif how == "indent":
            lines[i] = b" " * data.draw(st.integers(1, 3)) + lines[i]
        raw = b"\n".join(lines)
        if how == "garbage":
            raw = raw[:at] + data.draw(_GARBAGE_TEXT).encode("utf-8") + raw[at:]
        elif how == "non_utf8":
            raw = raw[:at] + data.draw(st.sampled_from([b"\xff", b"\xc3", b"\x80\x80", b"\xed\xa0\x80", b"\xfe\xff"])) + raw[at:]
        elif how == "truncate":
            raw = raw[:at]
    return raw


@fuzz(200)
@given(source=st.sampled_from(PROCEDURES + CONFIGS), data=st.data())
def test_textual_mutations_of_shipped_files_load_or_name_the_file(tree, source, data):
    kind = "procedure" if source.parent.name == "procedures" else "config"
    fuzzed = tree / source.parent.relative_to(ROOT) / f"fuzzed_{source.name}"
    fuzzed.write_bytes(_mutate_text(source.read_bytes(), data))
    _check_loads_or_names_file(kind, fuzzed)


_REFERENCES = [("configs/sim.yaml", "configs/sensors/acs_board_simple.yaml"),
               ("procedures/vibe_functional.yaml", "configs/vibration/low_level_sine_sweep.yaml"),
               ("procedures/vibe_functional.yaml", "configs/vibration/gevs_workmanship.yaml")]


@fuzz(40)
@given(pair=st.sampled_from(_REFERENCES), data=st.data())
def test_mutated_referenced_files_are_named_by_the_loader(tree, pair, data):
    """A sensor model (referenced by a config) or a vibration profile (by a procedure) damaged."""
    referencing, referenced = (tree / p for p in pair)
    original = referenced.read_bytes()
    referenced.write_bytes(_mutate_text(original, data))
    try:
        _load("config" if referencing.parent.name == "configs" else "procedure", referencing)
    except InputError as exc:
        assert referenced.name in str(exc), str(exc)
        assert all("\n" not in e.one_line() for e in (exc.errors if isinstance(exc, InputErrors) else [exc]))
    finally:
        referenced.write_bytes(original)


@pytest.mark.parametrize("tagged", [
    "schema: !!python/object/apply:os.system ['touch {marker}']",
    "instruments: !!python/object/apply:os.system ['touch {marker}']",
    "instruments: [!!python/object/apply:os.system ['touch {marker}']]",
    "? !!python/object/apply:os.system ['touch {marker}']\n: x",
    "title: !!python/object/new:os.system ['touch {marker}']",
    "title: !!python/name:os.system",
    "parameters: !!python/object:os.system {{a: 'touch {marker}'}}",
    "!!python/name:os.system title: x",
])
@pytest.mark.parametrize("kind", ["procedure", "config"])
def test_python_tags_are_refused_and_never_executed(tmp_path, tagged, kind):
    marker = tmp_path / "executed"
    head = ("schema: bench-procedure/1\nname: x\ninstruments: [acs_board]\nsteps: [{wait: {duration: 1 s}}]\n" if kind == "procedure"
            else "schema: bench-config/1\ninstruments: {acs_board: {driver: acs_board, port: /dev/x}}\n")
    lines = [ln for ln in head.splitlines() if ln.split(":")[0] != tagged.split(":")[0]]
    path = tmp_path / f"{kind}.yaml"
    path.write_text("\n".join(lines) + "\n" + tagged.format(marker=marker) + "\n")
    with pytest.raises(InputError) as info:
        _load(kind, path)
    assert str(info.value).startswith(f"{path}:"), str(info.value)
    assert re.search(r"YAML tag|cannot read value|mapping keys must be plain names", str(info.value)), str(info.value)
    assert not marker.exists()


@pytest.mark.parametrize("text, needle", [
    ("name: x\ninstruments: &a [*a]\n", "alias refers to the list or mapping that contains it"),
    ("steps: " + "[" * 3000 + "]" * 3000 + "\n", "nested too deeply"),
    ("a: &a [x,x,x,x,x,x,x,x,x,x]\nb: &b [*a,*a,*a,*a,*a,*a,*a,*a,*a,*a]\nc: &c [*b,*b,*b,*b,*b,*b,*b,*b,*b,*b]\n"
     "d: &d [*c,*c,*c,*c,*c,*c,*c,*c,*c,*c]\ne: &e [*d,*d,*d,*d,*d,*d,*d,*d,*d,*d]\nf: [*e,*e,*e,*e,*e,*e,*e,*e,*e,*e]\n",
     "more than 100000 values"),
    ("name: x\ntimeout: " + "9" * 400 + "\n", "too large"),
    ("name: x\ntimeout: " + "9" * 5000 + "\n", "cannot read value"),
    ("name: !!int abc\n", "cannot read value"),
    ("name: !!float abc\n", "cannot read value"),
    ("name: !!timestamp 2001-99-99\n", "cannot read value"),
    ("name: x\ninstruments: !!set {a, b}\n", "YAML tag"),
    ("name: x\x00\n", "2:8: not valid YAML: unacceptable character #x0000"),
])
def test_yaml_bugs_found_by_fuzzing_are_located_input_errors(tmp_path, text, needle):
    """Each of these raised RecursionError, OverflowError or ValueError (or loaded a tagged list
    silently, or took minutes for an alias bomb) before."""
    for kind in ("procedure", "config"):
        path = tmp_path / f"{kind}.yaml"
        path.write_text(f"schema: bench-{kind}/1\n" + text)
        with pytest.raises(InputError) as info:
            _load(kind, path)
        assert str(info.value).startswith(str(path)) and needle in str(info.value), str(info.value)
        assert "\n" not in str(info.value)


def test_non_utf8_file_names_its_line(tmp_path):
    path = tmp_path / "p.yaml"
    path.write_bytes(b"schema: bench-procedure/1\nname: x\ntitle: caf\xe9\n")
    with pytest.raises(InputError, match=rf"^{re.escape(str(path))}:3: cannot read procedure: byte 0xe9 is not UTF-8 text$"):
        load_procedure(path)


@pytest.mark.parametrize("value", ["9" * 400, "9" * 5000, "[" * 3000, "&a [*a]", "!!python/object/apply:os.system [true]"])
def test_parameter_overrides_never_escape(value):
    """``-p duration=...``: each of the first four raised OverflowError, ValueError or RecursionError."""
    with pytest.raises(InputError, match="duration"):
        load_procedure(ROOT / "procedures" / "allan_static.yaml", {"duration": value})


def test_nul_in_a_referenced_file_name_is_an_input_error(tmp_path):
    head = "schema: bench-procedure/1\nname: x\ninstruments: [acs_board]\nsteps:\n"
    for body in ['  - call: {procedure: "a\\0b"}', '  - vibrate: {profile: "a\\0b", axis: z}']:
        with pytest.raises(InputErrors, match=r"p\.yaml:5:\d+: \w+: expected a file name without NUL"):
            parse_procedure(head + body + "\n", str(tmp_path / "p.yaml"))
    config = (ROOT / "configs" / "sim.yaml").read_text().replace("sensor_model: sensors/acs_board_simple.yaml", 'sensor_model: "a\\0b"')
    (tmp_path / "c.yaml").write_text(config)
    with pytest.raises(InputErrors, match="sensor_model: sensor model .*cannot read sensor model"):
        load_config(tmp_path / "c.yaml")


@pytest.mark.parametrize("k", ["1.0e-320", ".inf", "0", "-3"])
def test_steps_per_degree_must_be_finite_and_usable(tmp_path, k):
    """speed_calibration k = 1e-320 raised ZeroDivisionError and .inf was accepted; its successor
    (GRBL's steps per degree) must be a usable number too."""
    text = (ROOT / "configs" / "sim.yaml").read_text().replace("      steps_per_deg: 894.33\n", f"      steps_per_deg: {k}\n")
    shutil.copytree(ROOT / "configs", tmp_path / "configs")
    path = tmp_path / "configs" / "k.yaml"
    path.write_text(text)
    with pytest.raises(InputErrors, match=rf"^{re.escape(str(path))}:\d+:\d+: steps_per_deg: (steps_per_deg must be a finite number|inf is not a finite quantity)"):
        load_config(path)


# =================================================================================================
# 3. measured-data CSV
# =================================================================================================
_FINITE = st.floats(allow_nan=False, allow_infinity=False, width=64)


@st.composite
def csv_datasets(draw, quoted: bool = True):
    """A valid measured-data CSV: columns, values, and its text in one of the accepted spellings
    (``quoted``: extra columns may hold quoted text with commas)."""
    known = [c for c in COLUMNS if c != "time_s"]
    cols = ["time_s"] + draw(st.lists(st.sampled_from(known), unique=True, max_size=6))
    if not any(c.startswith("gyro_") for c in cols):
        cols.append(draw(st.sampled_from(["gyro_x_dps", "gyro_y_dps", "gyro_z_dps"])))
    extra = draw(st.lists(st.sampled_from(["note", "operator", "x"]), unique=True, max_size=2))
    header = draw(st.permutations(cols + extra))
    n = draw(st.integers(1, 12))
    t = np.cumsum(draw(st.lists(st.floats(1e-6, 1e6), min_size=n, max_size=n))) + draw(st.floats(-1e6, 1e6))
    assume(np.all(np.diff(t) > 0))
    values = {c: [float(x) for x in t] if c == "time_s" else draw(st.lists(_FINITE, min_size=n, max_size=n)) for c in cols}
    text_or_number = st.one_of(_FINITE.map(repr), st.sampled_from(["ESTCube-2", "x y", "nan"]))
    meta = draw(st.fixed_dictionaries({}, optional={  # the numbers the analyses use within their ranges (dataset.META_RANGES)
        "sample_rate_hz": st.floats(1e-3, 1e7).map(repr), "latitude_deg": st.floats(-90, 90).map(repr),
        "unit": text_or_number, "serial": text_or_number}))
    lines = [f"# {k}: {v}" for k, v in meta.items()]
    lines.append(",".join(f" {h} " if draw(st.booleans()) else h for h in header))
    numbers: list[int] = []
    for i in range(n):
        while draw(st.integers(0, 5)) == 5:
            lines.append(draw(st.sampled_from(["", "# a comment", "   ", "#"])))
        cells = []
        for h in header:
            if h in values:
                cells.append(repr(values[h][i]) if draw(st.booleans()) else f"{values[h][i]:.17g}")
            else:
                cells.append(draw(st.sampled_from(["", "ok", "abc"] + (['"quoted, text"'] if quoted else []))))
        lines.append(",".join(cells))
        numbers.append(len(lines))
    eol = draw(st.sampled_from(["\n", "\r\n"]))
    text = eol.join(lines) + (eol if draw(st.booleans()) else "")
    bom = "\ufeff" if draw(st.booleans()) else ""
    return bom + text, values, meta, numbers


@fuzz(120)
@given(csv_datasets())
def test_valid_csv_round_trips(tmp_path, case):
    text, values, meta, numbers = case
    path = tmp_path / "data.csv"
    path.write_bytes(text.encode("utf-8"))
    ds = load_dataset(path)
    assert set(ds.columns) == set(values)
    for c, v in values.items():
        assert ds[c].tolist() == v
    assert ds.line_numbers.tolist() == numbers
    for k, v in meta.items():
        num = float(v) if v != "x y" and v != "ESTCube-2" else None
        assert ds.meta[k] == (num if num is not None and math.isfinite(num) else v)


_BAD_CELLS = ["", "abc", "nan", "NaN", "inf", "-inf", "1e999", "-1e400", "1_000", "0x10", "1,5", "--1", "1e", "\x00", "9" * 400]


@fuzz(120)
@given(case=csv_datasets(quoted=False), data=st.data())
def test_damaged_csv_gives_an_input_error_at_the_right_line(tmp_path, case, data):
    """One damage at a known row: the error names file:line (and the column when a cell is bad)."""
    text, values, meta, numbers = case
    lines = text.lstrip("\ufeff").replace("\r\n", "\n").split("\n")
    header_no = next(i for i, ln in enumerate(lines, 1) if ln.strip() and not ln.strip().startswith("#"))
    header = [h.strip() for h in lines[header_no - 1].split(",")]
    row = data.draw(st.integers(0, len(numbers) - 1))
    no = numbers[row]
    cells = lines[no - 1].split(",")
    how = data.draw(st.sampled_from(["cell", "ragged", "time", "drop_column", "quote"]))
    col = data.draw(st.sampled_from([c for c in header if c in values]))
    j = header.index(col)
    expect_line = no
    if how == "cell":
        bad = data.draw(st.sampled_from(_BAD_CELLS))
        cells[j] = bad
        needle = "expected a"
        if bad == "1,5":
            needle = "expected"  # the comma makes the row ragged
    elif how == "ragged":
        cells = cells[:-1] if data.draw(st.booleans()) and len(cells) > 1 else cells + ["1"]
        needle = "values like the header"
    elif how == "time":
        assume(row > 0)
        cells[header.index("time_s")] = repr(values["time_s"][row - 1] - data.draw(st.floats(0, 10)))
        needle = "time must increase"
    elif how == "drop_column":
        assume(col == "time_s" or sum(c.startswith("gyro_") for c in header if c in values) == 1 and col.startswith("gyro_"))
        hdr = lines[header_no - 1].split(",")
        hdr[j] = "renamed"
        lines[header_no - 1] = ",".join(hdr)
        expect_line = header_no
        needle = "missing required column" if col == "time_s" else "at least one gyro column"
    else:
        cells[j] = '"' + cells[j]  # an unterminated quote swallows the rest of the file
        needle = "not valid CSV"
    if how != "drop_column":
        lines[no - 1] = ",".join(cells)
    path = tmp_path / "bad.csv"
    path.write_text("\n".join(lines), encoding="utf-8")
    with pytest.raises(InputError) as info:
        dataset_from_csv(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}:{expect_line}:") or msg.startswith(f"{path}:{expect_line} "), (msg, how, expect_line)
    assert needle in msg, (msg, how)
    if how == "cell" and bad != "1,5":
        assert f": {col}: " in msg


@fuzz(100)
@given(st.one_of(st.binary(max_size=300), st.text(max_size=300).map(lambda s: s.encode("utf-8", "surrogatepass")),
                 st.lists(st.lists(st.sampled_from(["time_s", "gyro_x_dps", "1", "2.5", "-3", "nan", "", "#", '"', "\ufeff"]),
                                   max_size=4).map(",".join), max_size=8).map(lambda rows: "\n".join(rows).encode())))
def test_arbitrary_csv_bytes_load_or_raise_a_located_input_error(tmp_path, raw):
    path = tmp_path / "any.csv"
    path.write_bytes(raw)
    for read in (dataset_from_csv, lambda p: read_numeric_csv(p, ["time_s", "gyro_x_dps"])):
        try:
            out = read(path)
        except InputError as exc:
            assert str(exc).startswith(f"{path}:"), str(exc)  # every CSV error has a line
            continue
        if isinstance(out, tuple):
            out = out[0]
        cols = out.columns if hasattr(out, "columns") else out
        assert all(np.all(np.isfinite(v)) for v in cols.values())


@pytest.mark.parametrize("raw, where, needle", [
    (b"", 1, "no header line"),
    (b"\xef\xbb\xbf", 1, "no header line"),
    (b"# only: comments\n#\n\n", 1, "no header line"),
    (b"time_s,gyro_x_dps\n", 1, "no data rows"),
    (b"time_s,gyro_x_dps\n0,1\n1,\xff\n", 3, "not UTF-8"),
    (b"time_s,gyro_x_dps\n0,1\x0c\n1,2\n2,x\n", 4, "got 'x'"),
    (b"time_s,gyro_x_dps\n0,1\n1,\"2\n3\"\n4,zz\n", 3, "expected a number"),
    (b"time_s,gyro_x_dps,time_s\n0,1,2\n", 1, "column named twice"),
    (b"time_s,gyro_x_dps\n0,1\n1," + b"7" * 200_000 + b"\n", 3, "field larger than field limit"),
    (b"time_s,gyro_x_dps\n0,1\n1,2\n0.5,3\n", 4, "0.5 s follows 1.0 s"),
])
def test_csv_edge_cases(tmp_path, raw, where, needle):
    """The form feed, quoted newline, duplicate column, field limit and non-UTF-8 cases gave a wrong
    line or no line before; a quoted cell spanning two lines read as the number 23."""
    path = tmp_path / "e.csv"
    path.write_bytes(raw)
    with pytest.raises(InputError) as info:
        dataset_from_csv(path)
    assert str(info.value).startswith(f"{path}:{where}:") and needle in str(info.value), str(info.value)


# =================================================================================================
# 4. run files
# =================================================================================================
_WORKER = r"""
import io, json, sys, traceback
import numpy as np
from pathlib import Path
from rich.console import Console
from bench.errors import InputError
from bench.record.reader import read_run_summary, read_stream, render_summary
from bench.analysis.dataset import dataset_from_run

def attempt(fn):
    try:
        fn()
        return ["ok"]
    except InputError as exc:
        return ["InputError", str(exc)]
    except BaseException as exc:  # noqa: BLE001
        return ["other", f"{type(exc).__name__}: {exc}", traceback.format_exc()[-2000:]]

def dataset(path):
    d = dataset_from_run(path)
    t = d["time_s"]
    assert np.all(np.isfinite(t)) and np.all(np.diff(t) > 0), "time_s not finite and strictly increasing"
    assert all(v.shape[0] == t.shape[0] for v in d.columns.values()), "columns of unequal length"

print("ready", flush=True)
for line in sys.stdin:
    path = Path(line.rstrip("\n"))
    box, results = {}, {}
    def summary():
        box["s"] = read_run_summary(path)
        render_summary(box["s"], Console(file=io.StringIO(), width=120))
    results["summary"] = attempt(summary)
    for x in box["s"].streams if "s" in box else []:
        results["stream " + x.key] = attempt(lambda: read_stream(path, x.key))
    results["dataset"] = attempt(lambda: dataset(path))
    print(json.dumps(results), flush=True)
"""


class RunFileWorker:
    """Reads run files in a separate process, one at a time, with a time limit: a hang or a crash
    of HDF5 on a damaged file fails the test that found it instead of taking pytest down."""

    TIMEOUT_S = 60.0

    def __init__(self) -> None:
        self.proc: subprocess.Popen | None = None
        self.lock = threading.Lock()
        self.stderr = tempfile.TemporaryFile()

    def _start(self) -> None:
        self.proc = subprocess.Popen([sys.executable, "-c", _WORKER], cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=self.stderr, text=True)
        assert self._readline(120.0) == "ready\n", "run-file worker did not start"

    def _readline(self, timeout: float) -> str | None:
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout)
        return self.proc.stdout.readline() if ready else None

    def read(self, path: Path) -> dict[str, list[str]]:
        with self.lock:
            if self.proc is None or self.proc.poll() is not None:
                self._start()
            self.proc.stdin.write(f"{path}\n")
            self.proc.stdin.flush()
            line = self._readline(self.TIMEOUT_S)
            if line is None:
                self.close()
                pytest.fail(f"reading {path} hung (more than {self.TIMEOUT_S:.0f} s)")
            if not line:
                code = self.proc.wait()
                self.proc = None
                self.stderr.seek(0)
                pytest.fail(f"reading {path} crashed the process (exit code {code}): {self.stderr.read()[-2000:]!r}")
            return json.loads(line)

    def close(self) -> None:
        if self.proc is not None:
            self.proc.kill()
            self.proc.wait()
            self.proc = None


@pytest.fixture(scope="module")
def worker():
    w = RunFileWorker()
    yield w
    w.close()
    w.stderr.close()


def _assert_only_input_errors(path: Path, results: dict[str, list[str]]) -> None:
    for what, (outcome, *detail) in results.items():
        assert outcome in ("ok", "InputError"), f"{what} of {path}: {detail[0]}\n{detail[-1]}"
        if outcome == "InputError":
            msg = detail[0]
            assert msg.startswith(str(path)) and "\n" not in msg, (what, msg)
            if what == "summary":
                assert "not a readable bench run file" in msg or "is newer than this bench reads" in msg, msg


_EDIT = st.one_of(
    st.tuples(st.just("truncate"), st.floats(0, 1, exclude_max=True), st.just(b"")),
    st.tuples(st.just("overwrite"), st.floats(0, 1, exclude_max=True), st.binary(min_size=1, max_size=64)),
    st.tuples(st.just("tail"), st.integers(0, 4200), st.just(b"")),  # cut among the last blocks written (global heap, status)
)


@fuzz(60)
@given(source=st.sampled_from(SESSIONS), edits=st.lists(_EDIT, min_size=1, max_size=4))
def test_damaged_run_files_give_input_errors_never_a_crash(tmp_path, worker, source, edits):
    data = bytearray(source.read_bytes())
    for how, where, payload in edits:
        if how == "truncate":
            del data[int(where * len(data)):]
        elif how == "tail":
            del data[max(0, len(data) - where):]
        elif data:
            at = int(where * len(data))
            data[at:at + len(payload)] = payload
    path = tmp_path / f"damaged_{source.name}"
    path.write_bytes(bytes(data))
    _assert_only_input_errors(path, worker.read(path))


def test_truncation_inside_the_last_global_heap_is_refused_not_a_hang(tmp_path, worker):
    """Found by fuzzing: HDF5 2.0 loops forever reading a text attribute of a global heap collection
    whose end is missing (H5HG__cache_heap_deserialize on a zeroed object header)."""
    source = ROOT / "tests" / "sessions" / "chamber_interlock_abort.h5"
    data = source.read_bytes()
    gcol = data.rfind(b"GCOL")
    for cut in (gcol + 13, gcol + 40, gcol + 100):
        path = tmp_path / f"cut{cut}.h5"
        path.write_bytes(data[:cut])
        results = worker.read(path)
        _assert_only_input_errors(path, results)
        assert results["summary"][0] == "InputError" and "global heap" in results["summary"][1], results["summary"]
    path = tmp_path / "cut_late.h5"
    path.write_bytes(data[:len(data) - 100])  # the free-space object header survived: readable, with a warning
    assert worker.read(path)["summary"] == ["ok"]
    assert "truncated" in read_run_summary(path).warnings[0]


def test_zero_length_foreign_and_future_files(tmp_path):
    empty = tmp_path / "empty.h5"
    empty.write_bytes(b"")
    foreign = tmp_path / "foreign.h5"
    with h5py.File(foreign, "w") as f:
        f["x"] = np.arange(3)
        f.attrs["status"] = "completed"
    future = tmp_path / "future.h5"
    shutil.copy(SESSIONS[0], future)
    with h5py.File(future, "r+") as f:
        f.attrs["format_version"] = 999
    cases = {empty: "not a readable bench run file: the file is empty",
             foreign: "not a readable bench run file: no format_version attribute (not written by bench)",
             future: f"run file format_version 999 is newer than this bench reads (up to {FORMAT_VERSION}); upgrade bench to read it"}
    for path, message in cases.items():
        for read in (read_run_summary, dataset_from_run, load_dataset):
            with pytest.raises(InputError) as info:
                read(path)
            assert str(info.value) == f"{path}: {message}"


def _board_run_copy(tmp_path: Path) -> Path:
    path = tmp_path / "run.h5"
    shutil.copy(ROOT / "tests" / "sessions" / "rate_transfer_short.h5", path)
    return path


def test_dataset_from_run_keeps_time_strictly_increasing_and_finite(tmp_path):
    """A backward step of more than one row, or a NaN time, passed into the Dataset before."""
    path = _board_run_copy(tmp_path)
    with h5py.File(path, "r+") as f:
        t = f["streams/acs_board/time"]
        v = t[:]
        v[10], v[11], v[12] = v[30], v[5], v[6]  # jump ahead, then two rows back in time
        v[0] = np.nan
        t[...] = v
    ds = dataset_from_run(path)
    t = ds["time_s"]
    assert np.all(np.isfinite(t)) and np.all(np.diff(t) > 0)
    assert len(ds) == v.size - 1 - 2 - 18  # NaN row, the two stepping back, rows 13..30 at or before v[30]


@pytest.mark.parametrize("change, needle", [
    (lambda g: (g.__delitem__("gyro"), g.create_dataset("gyro", data=np.zeros(g["time"].shape[0]))), "'gyro' of stream 'acs_board' has shape"),
    (lambda g: g.move("accel", "accelerometer"), "stream 'acs_board' has no column 'accel'"),
    (lambda g: (g.__delitem__("temp"), g.create_dataset("temp", data=np.array(["x"] * g["time"].shape[0], dtype="S1"))), "not numeric"),
])
def test_dataset_from_run_with_missing_or_misshapen_columns(tmp_path, change, needle):
    """A KeyError or IndexError escaped before."""
    path = _board_run_copy(tmp_path)
    with h5py.File(path, "r+") as f:
        change(f["streams/acs_board"])
    with pytest.raises(InputError, match=re.escape(needle)) as info:
        dataset_from_run(path)
    assert str(info.value).startswith(f"{path}: ")


def test_latitude_of_an_unreadable_recorded_config_is_unknown():
    """RecursionError / ValueError escaped from the latitude lookup of ``dataset_from_run`` before."""
    from bench.analysis.dataset import _latitude_from_config

    for text in ("x: " + "[" * 3000, "world: {latitude: " + "9" * 5000 + "}", "world: [1]", "- a", "\x00"):
        assert _latitude_from_config(text) is None
    assert _latitude_from_config("world: {latitude: 36.4 deg}") == pytest.approx(36.4)


# =================================================================================================
# 5. the CLI end to end
# =================================================================================================
def test_cli_exits_2_without_traceback_on_fuzzed_inputs(tmp_path):
    """``bench validate`` (procedure, and config with --config) and ``bench inspect`` on inputs that
    each raised RecursionError, loaded a tagged list, or hung before."""
    startup = ROOT / "procedures" / "startup_profile.yaml"
    session = (ROOT / "tests" / "sessions" / "chamber_interlock_abort.h5").read_bytes()
    overwritten = bytearray(session)
    overwritten[96:160] = bytes(range(64))
    files = {
        "tag.yaml": startup.read_bytes().replace(b"instruments: [acs_board]", b"instruments: !!python/object/apply:os.system [acs_board]"),
        "nested.yaml": startup.read_bytes() + b"x: " + b"[" * 3000 + b"\n",
        "latin1_config.yaml": (ROOT / "configs" / "sim.yaml").read_bytes().replace(b"name: simulated-lab", b"name: simul\xe9"),
        "gcol_cut.h5": session[: session.rfind(b"GCOL") + 40],
        "overwritten.h5": bytes(overwritten),
    }
    jobs = []
    for name, content in files.items():
        path = tmp_path / name
        path.write_bytes(content)
        if name.endswith(".h5"):
            cmd = ["inspect", str(path)]
        elif "config" in name:
            cmd = ["validate", str(startup), "--config", str(path)]
        else:
            cmd = ["validate", str(path)]
        jobs.append((path, subprocess.Popen([sys.executable, "-m", "bench", *cmd], cwd=ROOT, stdout=subprocess.PIPE,
                                            stderr=subprocess.PIPE, text=True)))
    for path, proc in jobs:
        try:
            out, err = proc.communicate(timeout=120)
        except subprocess.TimeoutExpired:
            proc.kill()
            pytest.fail(f"bench on {path.name} did not finish")
        assert proc.returncode == 2, (path.name, proc.returncode, out[-500:], err[-2000:])
        assert "Traceback" not in err and "internal error" not in err, (path.name, err[-2000:])
        assert err.startswith(str(path)), (path.name, err[-500:])


# =================================================================================================
# 6. crafted and damaged run files: replay and every reader (issue 21; docs/reliability.md,
#    "Crafted and damaged run files")
# =================================================================================================
SHORT_PROCEDURE = """schema: bench-procedure/1
name: fuzz_short
instruments: [acs_board, tvac]
steps:
  - power: {instrument: acs_board, on: true, name: sensors on}
  - record: {instrument: acs_board, duration: 2 s, window: still, name: still}
  - power: {instrument: acs_board, on: false, name: sensors off}
"""


@pytest.fixture(scope="session")
def short_run(tmp_path_factory) -> Path:
    """A small real run file, made once: a dry-run of a 2 s board recording with the chamber polled
    (a board stream and a monitor stream, the procedure and config texts, the traffic)."""
    from tests.conftest import SIM_CONFIG, run_cli

    d = tmp_path_factory.mktemp("short_run")
    proc = d / "fuzz_short.yaml"
    proc.write_text(SHORT_PROCEDURE)
    r = run_cli("run", str(proc), "--config", str(SIM_CONFIG), "--sim", "--runs-dir", str(d / "runs"), timeout=300)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    (path,) = (d / "runs").glob("*.h5")
    return path


_HDF5_SIGNATURES = (b"OHDR", b"OCHK", b"GCOL", b"TREE", b"HEAP", b"SNOD", b"BTHD", b"BTLF", b"BTIN", b"FRHP", b"FHDB", b"FHIB",
                    b"FSHD", b"FSSE", b"EAHD", b"EAIB", b"EADB", b"FAHD", b"FADB")
SWEEP_BYTES = 64 * 1024
REPORTED_CUTS = (1136, 11365)
"""Truncation points at which ``bench replay`` hung for more than 200 s (issue 21)."""


def structural_cuts(data: bytes, limit: int = SWEEP_BYTES) -> list[int]:
    """Offsets that cut the file inside its HDF5 structures: at and just after the start of every
    metadata block (object headers, B-trees, heaps, global heaps, free-space and array blocks) of
    its first ``limit`` bytes, inside the superblock, and the points reported in issue 21."""
    cuts = {8, 9, 24, 48, 96, *REPORTED_CUTS}
    for sig in _HDF5_SIGNATURES:
        at = data.find(sig)
        while 0 <= at < limit:
            cuts.update(at + d for d in (0, 1, 4, 9, 17, 40))
            at = data.find(sig, at + 1)
    return sorted(c for c in cuts if 0 <= c < min(limit, len(data)))


_SWEEP = r"""
import json, os, sys, time
from pathlib import Path
from bench.errors import InputError
from bench.record.reader import read_stream
from bench.replay.recording import load_recording

src, cut, offsets = Path(sys.argv[1]), Path(sys.argv[2]), json.loads(sys.stdin.read())
data = src.read_bytes()
cut.write_bytes(data[:max(offsets)])
worst, bad = [0.0, -1], []

def attempt(n, what, fn):
    try:
        fn()
    except InputError as exc:
        msg = str(exc)
        if not msg.startswith(str(cut)) or "\n" in msg:
            bad.append([n, what, "InputError not located on one line: " + msg[:500]])
        return None
    except BaseException as exc:  # noqa: BLE001
        bad.append([n, what, f"{type(exc).__name__}: {exc}"[:500]])
        return None
    return True

for n in sorted(offsets, reverse=True):  # the file is cut shorter and shorter
    print(n, flush=True)  # the last offset printed is the one that hung, if one does
    os.truncate(cut, n)
    t0 = time.monotonic()
    box = {}
    if attempt(n, "replay", lambda: box.setdefault("rec", load_recording(cut))):
        for s in box["rec"].summary.streams:
            attempt(n, "stream " + s.key, lambda: read_stream(cut, s.key))
    dt = time.monotonic() - t0
    if dt > worst[0]:
        worst = [dt, n]
print(json.dumps({"worst": worst, "bad": bad}), flush=True)
"""


def _sweep(tmp_path: Path, run_file: Path, offsets: list[int], timeout_s: float, workers: int = 2) -> dict:
    """Cut ``run_file`` at every offset (longest first) and open each cut with the replay's reader
    (version check, summary, the 'procedure' event) and every stream, the offsets shared among
    ``workers`` processes (each with its own copy; CI has 2 cores); what went wrong and the slowest
    offset. A hang fails with the offset it hung at."""
    import time

    procs = [subprocess.Popen([sys.executable, "-c", _SWEEP, str(run_file), str(tmp_path / f"cut{i}.h5")],
                              cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for i in range(workers)]
    for i, proc in enumerate(procs):  # every worker has its offsets before any is waited for
        proc.stdin.write(json.dumps(offsets[i::workers]))
        proc.stdin.close()
        proc.stdin = None  # closed: communicate() only reads
    deadline = time.monotonic() + timeout_s
    results = []
    try:
        for proc in procs:
            try:
                out, err = proc.communicate(timeout=max(1.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                proc.kill()
                out, err = proc.communicate()
                last = out.split()[-1] if out.split() else "?"
                pytest.fail(f"reading {run_file.name} cut at {last} bytes hung (sweep over {timeout_s:.0f} s)")
            assert proc.returncode == 0, f"the sweep crashed (exit {proc.returncode}) after offset {out.split()[-1:]}: {err[-2000:]}"
            results.append(json.loads(out.splitlines()[-1]))
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
    return {"worst": max((r["worst"] for r in results), key=lambda w: w[0]), "bad": [b for r in results for b in r["bad"]]}


def test_truncated_run_files_are_refused_in_bounded_time_fast_sweep(tmp_path, short_run):
    """The replay's version check opened a truncated file without the reader's limits: `bench
    replay` of files cut at 1,136 or 11,365 bytes hung for more than 200 s. Every cut inside the
    HDF5 structures of the first 64 KiB, and every 509th byte, now opens or is refused with one
    located line, in seconds."""
    data = short_run.read_bytes()
    offsets = sorted(set(structural_cuts(data)) | set(range(0, SWEEP_BYTES, 509)))
    result = _sweep(tmp_path, short_run, offsets, timeout_s=240)
    assert not result["bad"], result["bad"][:5]
    assert result["worst"][0] < 10.0, f"slowest cut: {result['worst'][1]} bytes in {result['worst'][0]:.1f} s"


@pytest.mark.slow
def test_truncated_run_files_are_refused_in_bounded_time_every_byte(tmp_path, short_run):
    """As the fast sweep, at every byte offset of the first 64 KiB (65,537 cuts: 19 min on a loaded
    2-core machine, slowest cut 1.0 s; BENCH_SLOW=1)."""
    result = _sweep(tmp_path, short_run, list(range(0, SWEEP_BYTES + 1)), timeout_s=4 * 3600)
    assert not result["bad"], result["bad"][:5]
    assert result["worst"][0] < 10.0, f"slowest cut: {result['worst'][1]} bytes in {result['worst'][0]:.1f} s"


def _run_all(jobs: list[tuple[str, list[str], Path]], timeout_s: float = 60.0, parallel: int = 4) -> dict[str, tuple[int, str, str, float]]:
    """Run ``python -m bench ARGS`` for every ``(label, args, cwd)``, ``parallel`` at a time, each
    with a time limit; ``label -> (exit code, stdout, stderr, wall s)``. A job over its limit fails the test."""
    import time

    results, pending = {}, list(jobs)
    running: list[tuple[str, subprocess.Popen, float]] = []
    while pending or running:
        while pending and len(running) < parallel:
            label, args, cwd = pending.pop(0)
            running.append((label, subprocess.Popen([sys.executable, "-m", "bench", *args], cwd=cwd, stdout=subprocess.PIPE,
                                                    stderr=subprocess.PIPE, text=True), time.monotonic()))
        label, proc, t0 = running.pop(0)
        try:
            out, err = proc.communicate(timeout=max(1.0, timeout_s - (time.monotonic() - t0)))
        except subprocess.TimeoutExpired:
            for _, p, _ in running + [(label, proc, t0)]:
                p.kill()
            pytest.fail(f"bench {label} did not finish within {timeout_s:.0f} s")
        results[label] = (proc.returncode, out, err, time.monotonic() - t0)
    return results


def test_cli_on_truncated_run_files_exits_2_with_one_line(tmp_path, short_run):
    """`bench replay` and `bench inspect` on cuts at the reported points and inside the first
    HDF5 structures; `report`, `diagnose`, `calibrate` and `catalog rebuild` at the reported
    points: every one finishes in seconds, refusing with exit 2 and one located line (catalog
    rebuild: exit 1, the file listed as unreadable), never a traceback."""
    data = short_run.read_bytes()
    structural = [c for c in structural_cuts(data) if c > 48]
    picks = sorted(set(REPORTED_CUTS) | set(structural[:: max(1, len(structural) // 4)][:4]))
    jobs = []
    for n in picks:
        path = tmp_path / f"cut{n}.h5"
        path.write_bytes(data[:n])
        with pytest.raises(InputError):  # the premise: this cut is not a readable run file
            read_run_summary(path)
        jobs += [(f"replay {path.name}", ["replay", str(path), "--runs-dir", str(tmp_path / "replays")], tmp_path),
                 (f"inspect {path.name}", ["inspect", str(path)], tmp_path)]
    for n in REPORTED_CUTS:
        path = tmp_path / f"cut{n}.h5"
        jobs += [(f"report {path.name}", ["report", str(path), "-o", str(tmp_path / f"r{n}.html")], tmp_path),
                 (f"diagnose {path.name}", ["diagnose", str(path)], tmp_path),
                 (f"calibrate {path.name}", ["calibrate", "noise", str(path)], tmp_path)]
        cat = tmp_path / f"catalog{n}"
        cat.mkdir()
        shutil.copy(path, cat / path.name)
        jobs.append((f"catalog {path.name}", ["catalog", "rebuild", str(cat)], tmp_path))
    for label, (rc, out, err, wall) in _run_all(jobs).items():
        assert "Traceback" not in out + err and "internal error" not in err, (label, err[-2000:])
        assert wall < 30.0, (label, wall)
        name = label.split()[1]
        if label.startswith("catalog"):
            assert rc == 1 and name in err and "unreadable" in out + err, (label, rc, out[-500:], err[-500:])
            continue
        line = one_error_line(subprocess.CompletedProcess(label, rc, out, err))  # progress lines may come before
        assert line.startswith(str(tmp_path / name)), (label, err[-1000:])


def test_a_fifo_or_device_named_as_a_run_file_is_refused_not_waited_on(tmp_path, worker):
    """Opening a FIFO as a run file blocked forever (the reader read its signature with open())."""
    fifo = tmp_path / "fifo.h5"
    os.mkfifo(fifo)
    for path in (fifo, Path("/dev/zero")):
        results = worker.read(path)
        assert results["summary"][0] == "InputError" and "not a regular file" in results["summary"][1], results
        _assert_only_input_errors(path, results)


def craft(src: Path, dst: Path, *, attrs: dict | None = None, config_text: str | None = None, procedure_text: str | None = None,
          procedure_event: dict | None = None, move: dict[str, str] | None = None, edit=None) -> Path:
    """A copy of the run file ``src`` at ``dst`` with root attributes, the procedure or config text,
    keys of the 'procedure' event's JSON, or the names of groups (``move``: old path -> new path)
    changed, as a hostile file would have them; ``edit(h5py.File)`` for anything else."""
    from bench.record import layout
    from bench.record.skeleton import write_text

    shutil.copy(src, dst)
    with h5py.File(dst, "r+") as f:
        for k, v in (attrs or {}).items():
            f.attrs[k] = v
        for group, text in ((layout.PROCEDURE, procedure_text), (layout.CONFIG, config_text)):
            if text is not None:
                del f[group][layout.TEXT]
                write_text(f[group], text)
        if procedure_event is not None:
            rows, blob = f[layout.EVENTS], f[layout.EVENTS_BLOB]
            (i,) = np.flatnonzero(rows["kind"][:] == b"procedure")
            row = rows[i]
            info = json.loads(blob[row["data_off"]:row["data_off"] + row["data_len"]].tobytes())
            data = json.dumps({**info, **procedure_event}).encode()
            at = blob.shape[0]
            blob.resize((at + len(data),))
            blob[at:] = np.frombuffer(data, dtype=np.uint8)
            row["data_off"], row["data_len"] = at, len(data)
            rows[i] = row
        for old, new in (move or {}).items():
            f.move(old, new)
        if edit is not None:
            edit(f)
    return dst


_CRAFTED_WORKER = r"""
import contextlib, io, json, os, sys, tempfile
os.environ["COLUMNS"] = "400"
events = []
WATCHED = ("open", "os.mkdir", "os.symlink", "os.link", "os.rename", "os.remove", "os.rmdir", "os.truncate", "os.chmod",
           "os.listdir", "os.scandir", "shutil.copyfile", "shutil.rmtree")
def hook(event, args):
    if event in WATCHED and args and isinstance(args[0], (str, bytes)):
        events.append([event, os.fsdecode(args[0])])
sys.addaudithook(hook)
from bench.cli import main

out = {}
for case in json.loads(sys.stdin.read()):
    tempfile.tempdir = case["tmpdir"]  # where a replay makes its private directory
    os.chdir(case["cwd"])
    events.clear()
    o, e = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(o), contextlib.redirect_stderr(e):
        rc = main(["replay", case["run_file"], "--runs-dir", case["runs_dir"]])
    touched = [ev for ev in events if ev[1].startswith(case["foreign"])]
    out[case["label"]] = [rc, o.getvalue(), e.getvalue(), touched]
print(json.dumps(out))
"""


def _listing(*dirs: Path) -> dict[str, list[str]]:
    return {str(d): sorted(str(p.relative_to(d)) for p in d.rglob("*")) for d in dirs}


def replay_crafted(tmp_path: Path, cases: dict[str, Path], foreign: Path) -> dict[str, tuple[int, str, str, list]]:
    """``bench replay`` of every crafted file in one worker process (in-process replays, one import),
    each in a fresh working directory with its own temporary directory; returns ``label -> (exit
    code, stdout, stderr, file-system calls on paths under foreign)`` and checks that nothing
    was created, changed or removed in ``foreign``, the working directory or the temporary
    directory (the replay's private directory is gone afterwards): only files in the runs directory."""
    jobs, dirs = [], {}
    for label, path in cases.items():
        base = tmp_path / f"case_{len(jobs)}"
        cwd, tmpdir, runs = base / "cwd", base / "tmp", base / "runs"
        for d in (cwd, tmpdir, runs):
            d.mkdir(parents=True)
        dirs[label] = (cwd, tmpdir)
        jobs.append({"label": label, "run_file": str(path), "runs_dir": str(runs), "cwd": str(cwd), "tmpdir": str(tmpdir),
                     "foreign": str(foreign)})
    before = _listing(foreign)
    proc = subprocess.run([sys.executable, "-c", _CRAFTED_WORKER], input=json.dumps(jobs), cwd=ROOT, capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    results = json.loads(proc.stdout.splitlines()[-1])
    assert _listing(foreign) == before, "a replay created, changed or removed files outside its directories"
    for label, (cwd, tmpdir) in dirs.items():
        base = cwd.parent
        left = sorted(str(p.relative_to(base)) for p in base.rglob("*") if p.parent != base / "runs")
        assert left == ["cwd", "runs", "tmp"], (label, left)
    return results


def test_crafted_paths_in_a_run_file_never_reach_the_file_system(tmp_path, short_run):
    """A crafted run file made `bench replay` create a symbolic link where the file said (its
    config named a sensor model with '..'), and a stored procedure path made it read (and quote)
    files next to that path. Recorded paths and texts are data now: they are written into the
    replay's private directory and read from there; a name that leaves it is refused, located in
    the run file, and nothing outside is read or written."""
    from bench.record import layout

    foreign = tmp_path / "foreign"
    (foreign / "c" / "d" / "e").mkdir(parents=True)
    (foreign / "foreign" / "sentinel").mkdir(parents=True)
    (foreign / "foreign" / "sentinel" / "planted.yaml").write_text("schema: bench-sensor-model/1\n")
    (foreign / "sentinel").mkdir()  # where the old replay made its link: case_N/tmp/bench-replay-X/../../../foreign/sentinel
    (foreign / "secret.yaml").write_text("TOPSECRET_7f3a: 1\n")
    (foreign / "profile.yaml").write_text("TOPSECRET_7f3a: 2\n")
    summary = read_run_summary(short_run)
    config = summary.config_text
    assert "sensor_model: sensors/acs_board_simple.yaml" in config
    proc = summary.procedure_text
    call = proc + "  - call: {procedure: secret.yaml}\n"
    shake = proc + "  - vibrate: {profile: profile.yaml, axis: z}\n"
    foreign_proc = str(foreign / "proc.yaml")
    cases = {
        # the reported attack: the old replay linked <its temp dir>/../../sentinel/planted.yaml
        "sensor model ..": craft(short_run, tmp_path / "a.h5", attrs={layout.ATTR_CONFIG_PATH: str(foreign / "c" / "d" / "e" / "sim.yaml")},
                                 config_text=config.replace("sensors/acs_board_simple.yaml", "../../../foreign/sentinel/planted.yaml")),
        "call next to the recorded path": craft(short_run, tmp_path / "b.h5", procedure_text=call, attrs={layout.ATTR_PROCEDURE_PATH: foreign_proc},
                                                procedure_event={"path": foreign_proc}),
        "profile next to the recorded path": craft(short_run, tmp_path / "c.h5", procedure_text=shake,
                                                   attrs={layout.ATTR_PROCEDURE_PATH: foreign_proc}, procedure_event={"path": foreign_proc}),
        "absolute call": craft(short_run, tmp_path / "d.h5", procedure_text=proc + f"  - call: {{procedure: {foreign / 'secret.yaml'}}}\n"),
        "sources key with ..": craft(short_run, tmp_path / "e.h5", procedure_event={"sources": {f"{foreign}/../foreign/secret.yaml": "x"}}),
        "relative sources key": craft(short_run, tmp_path / "f.h5", procedure_event={"sources": {"../../secret.yaml": "x"}}),
        "NUL in a sources key": craft(short_run, tmp_path / "g.h5", procedure_event={"sources": {"/tmp/a\0b.yaml": "x"}}),
        "very long sources key": craft(short_run, tmp_path / "h.h5", procedure_event={"sources": {"/" + "a" * 300 + "/b.yaml": "x"}}),
        "NUL in the procedure path": craft(short_run, tmp_path / "i.h5", procedure_event={"path": "/tmp/a\0b.yaml"}),
        "very long config path": craft(short_run, tmp_path / "k.h5", attrs={layout.ATTR_CONFIG_PATH: "/" + "c" * 5000 + ".yaml"}),
        "instrument name ..": craft(short_run, tmp_path / "l.h5", config_text=config.replace("\n  thermocouples:", "\n  ../../evil:", 1)),
        "stream name ..": craft(short_run, tmp_path / "m.h5", move={"streams/tvac": "streams/.."}),
        "very long instrument group": craft(short_run, tmp_path / "n.h5", move={"instruments/tvac": "instruments/" + "t" * 300}),
        "board column of another shape": craft(short_run, tmp_path / "q.h5", edit=lambda f: (
            f.move("streams/acs_board/temp", "streams/acs_board/old_temp"),
            f["streams/acs_board"].create_dataset("temp", data=f["streams/acs_board/old_temp"][:, 0]))),
    }
    harmless = {  # recorded paths that only place a text: replayed as usual, inside the private directory
        "config path with ..": craft(short_run, tmp_path / "o.h5", attrs={layout.ATTR_CONFIG_PATH: "../../../../../" + str(foreign / "sim.yaml")}),
        "procedure path with ..": craft(short_run, tmp_path / "p.h5", procedure_event={"path": "/../../" + str(foreign / "x.yaml")}),
    }
    results = replay_crafted(tmp_path, cases | harmless, foreign)
    for label, (rc, out, err, touched) in results.items():
        path = (cases | harmless)[label]
        assert not touched, (label, touched)  # not even looked at
        assert "TOPSECRET" not in out + err, (label, err[-1000:])
        if label in harmless:
            assert rc == 0 and "MATCH" in out and not err, (label, rc, out[-1000:], err[-1000:])
            continue
        assert rc == 2, (label, rc, out[-1000:], err[-1000:])
        lines = err.strip().splitlines()
        assert lines and all(line.startswith(str(path)) for line in lines), (label, err[-1000:])
        assert "Traceback" not in err and "internal error" not in err, (label, err[-1000:])
    assert "/config/text:" in results["sensor model .."][2] and "sensor_model" in results["sensor model .."][2]
    # refused by replay's own check of recorded names, or first by the recorded config's loader
    assert ("'../../evil' is not a plain name" in results["instrument name .."][2]
            or "instrument name '../../evil'" in results["instrument name .."][2]), results["instrument name .."][2]
    assert "column temp of board stream /streams/acs_board is of row shape ()" in results["board column of another shape"][2]
    for label in ("call next to the recorded path", "profile next to the recorded path", "absolute call"):
        assert "/procedure/text:" in results[label][2], (label, results[label][2])


def _replay_cli(tmp_path: Path, run_file: Path) -> tuple[int, str]:
    import argparse

    from rich.console import Console

    from bench.replay.cli import cmd_replay

    console = Console(record=True, width=300)
    rc = cmd_replay(argparse.Namespace(run_file=run_file, procedure=None, runs_dir=tmp_path / "replays", no_board_check=False), console)
    return rc, console.export_text()


@pytest.mark.parametrize("stream, column", [("acs_board", "temp"), ("tvac/monitor", "mount_temp")], ids=["board samples", "polled readings"])
def test_a_recorded_value_changed_in_the_file_diverges_on_replay(tmp_path, short_run, stream, column):
    """Adding 10 degC to every recorded board temperature replayed as MATCH: the replay sends the
    board's recorded rows, so its own stream equals them. A dry-run's board samples are now checked
    against a re-simulation, polled readings against the recorded replies; the message names the
    stream, the column, the first differing run time and both values."""
    rc, text = _replay_cli(tmp_path, short_run)
    assert rc == 0 and "MATCH" in text, text  # the untouched file
    path = tmp_path / "tampered.h5"
    shutil.copy(short_run, path)
    with h5py.File(path, "r+") as f:
        g = f["streams"][stream]
        first = np.asarray(g[column][0], dtype=float)
        g[column][...] = g[column][...] + 10.0
        t0 = float(g["time"][0])
    rc, text = _replay_cli(tmp_path, path)
    assert rc == 1 and "DIVERGED" in text, text
    first_div = text.split("DIVERGED: ", 1)[1]
    assert f"stream {stream} column {column}" in first_div.splitlines()[0], text
    assert f"at run time {t0:.6f} s" in first_div, text
    shown = lambda a: ", ".join(f"{x:.10g}" for x in np.atleast_1d(a))  # noqa: E731
    assert shown(first + 10.0) in first_div and shown(first) in first_div, text
