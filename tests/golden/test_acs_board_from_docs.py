"""ACS board: a decoder written only from docs/acs-board-protocol.md (framing, field layout, scales,
CRC-16) and docs/acs-board-can.md (CAN tunnel ids and segmentation) reads what the simulated board
sends, over its sim:// serial link and over CAN, and must agree sample by sample with the driver.
The document's worked examples are checked literally against both.

Nothing below the marked line imports from ``drivers``: the decoder is the document's.
Units: gyro deg/s, accelerometer g, magnetometer µT, temperature °C, board time s.
"""

from __future__ import annotations

import struct
import time
from dataclasses import dataclass, field

import numpy as np
import serial

# ================= the decoder, from docs/acs-board-protocol.md alone =========================
SYNC = bytes([0xA5, 0x5A])  # "sync | A5 5A"
HEADER = 4  # sync (2), type, len
OVERHEAD = 6  # header + CRC (2)
TYPE_DATA, TYPE_NAK = 0x01, 0x7F
COMMANDS = {"IDENTIFY": 0x10, "START_STREAM": 0x11, "STOP_STREAM": 0x12, "SET_ODR": 0x13,
            "SET_MOVING_AVG": 0x14, "RUN_BIT": 0x15, "SENSOR_POWER": 0x16, "GET_CONFIG": 0x17}
ACK_BIT = 0x80  # "type command | 0x80"
KNOWN_TYPES = {TYPE_DATA, TYPE_NAK} | set(COMMANDS.values()) | {c | ACK_BIT for c in COMMANDS.values()}
DATA_LEN = 32  # "a data frame must have len = 32"
MAX_PAYLOAD = 128  # "any other frame len <= MAX_PAYLOAD (currently 128 bytes)"
DATA_FORMAT = "<HI3h3h3h3hH"  # offsets 4 counter <u2, 6 board_time_us <u4, 10/16/22/28 3 x <i2, 34 status <u2
GYRO_DPS_PER_LSB = 250 / 32768
ACCEL_G_PER_LSB = 2 / 32768
MAG_UT_PER_LSB = 100 / 6842
TEMP_DEGC_PER_LSB = 0.01
BOARD_TIME_S_PER_US = 1e-6
BOARD_TIME_WRAP = 2**32  # µs
CONFIG_FORMAT = "<HBBBI"  # GET_CONFIG ACK: odr_hz, moving_avg_n, streaming, sensor_power, baud


def crc16_ccitt(data: bytes) -> int:
    """CRC-16/XMODEM as the document describes it: polynomial 0x1021, initial value 0, no reflection,
    no final XOR; bit by bit, most significant bit first."""
    crc = 0
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


@dataclass
class DocDecoder:
    """The document's sequential scan (section "Receiving"), one frame at a time."""

    samples: list[dict] = field(default_factory=list)
    frames: list[tuple[int, bytes]] = field(default_factory=list)  # non-data frames (type, payload)
    crc_errors: int = 0
    garbage_bytes: int = 0
    dropped_frames: int = 0
    _held: bytes = b""
    _last_counter: int | None = None
    _last_time_us: int | None = None
    _wraps: int = 0

    def feed(self, data: bytes) -> None:
        buf = self._held + bytes(data)
        pos = 0
        while True:
            start = buf.find(SYNC, pos)  # 1. next sync word
            if start < 0:
                keep = len(buf) - 1 if buf.endswith(SYNC[:1]) else len(buf)  # a trailing A5 may start a sync
                self.garbage_bytes += max(keep - pos, 0)
                self._held = buf[max(keep, pos):]
                return
            self.garbage_bytes += start - pos
            if len(buf) < start + HEADER:  # 2. header not complete: keep for the next feed
                self._held = buf[start:]
                return
            ftype, length = buf[start + 2], buf[start + 3]
            plausible = ftype in KNOWN_TYPES and (length == DATA_LEN if ftype == TYPE_DATA else length <= MAX_PAYLOAD)
            if not plausible:  # 3. skip one byte
                self.garbage_bytes += 1
                pos = start + 1
                continue
            end = start + OVERHEAD + length
            if len(buf) < end:  # 2. frame not complete
                self._held = buf[start:]
                return
            if crc16_ccitt(buf[start + 2:end - 2]) != int.from_bytes(buf[end - 2:end], "big"):  # 4.
                self.crc_errors += 1
                self.garbage_bytes += 1
                pos = start + 1
                continue
            self._accept(ftype, buf[start:end])  # 5.
            pos = end

    def _accept(self, ftype: int, frame: bytes) -> None:
        if ftype != TYPE_DATA:
            self.frames.append((ftype, frame[HEADER:-2]))
            return
        counter, t_us, *raw, status = struct.unpack_from(DATA_FORMAT, frame, HEADER)
        if self._last_counter is not None:
            self.dropped_frames += (counter - self._last_counter - 1) % 65536
        if self._last_time_us is not None and t_us < self._last_time_us:
            self._wraps += 1
        self._last_counter, self._last_time_us = counter, t_us
        self.samples.append({
            "counter": counter,
            "board_time_s": (t_us + self._wraps * BOARD_TIME_WRAP) * BOARD_TIME_S_PER_US,
            "gyro_dps": [v * GYRO_DPS_PER_LSB for v in raw[0:3]],
            "accel_g": [v * ACCEL_G_PER_LSB for v in raw[3:6]],
            "mag_ut": [v * MAG_UT_PER_LSB for v in raw[6:9]],
            "temp_degc": [v * TEMP_DEGC_PER_LSB for v in raw[9:12]],
            "status": status,
        })


def parse_config(payload: bytes) -> dict:
    odr, n, streaming, power, baud = struct.unpack(CONFIG_FORMAT, payload)
    return {"odr_hz": odr, "moving_avg_n": n, "streaming": bool(streaming), "sensor_power": bool(power), "baud": baud}


# CAN tunnel (docs/acs-board-can.md): board node N, host -> board 0x300 + N, board -> host 0x380 + N
BOARD_NODE = 16
HOST_TO_BOARD, BOARD_TO_HOST = 0x300 + BOARD_NODE, 0x380 + BOARD_NODE

# Worked examples, transcribed from docs/acs-board-protocol.md
EXAMPLES = {
    "IDENTIFY command": "A5 5A 10 00 03 73",
    "SET_ODR 200 Hz": "A5 5A 13 02 C8 00 71 E6",
    "SET_ODR ACK": "A5 5A 93 00 4D B8",
    "NAK of SET_ODR, BAD_VALUE": "A5 5A 7F 02 13 03 9E B8",
    "GET_CONFIG ACK": "A5 5A 97 09 64 00 01 00 00 00 C2 01 00 77 29",
}
DATA_EXAMPLE = ("A5 5A 01 20 01 00 40 42 0F 00 83 00 7D FF 00 00\n"
                "00 00 00 00 00 40 5D 0D 00 00 46 E5 C4 09 CE 09\n"
                "60 09 03 00 59 42")
DATA_EXAMPLE_DECODED = {"counter": 1, "board_time_s": 1.0, "gyro_dps": [0.99945068359375, -0.99945068359375, 0.0],
                        "accel_g": [0.0, 0.0, 1.0], "mag_ut": [50.0, 0.0, -100.0], "temp_degc": [25.00, 25.10, 24.00],
                        "status": 0x0003}

# ================= below: the code under test ====================================================
from bench.clock import VirtualClock  # noqa: E402
from bench.config import load_config  # noqa: E402
from bench.sim.can_serial_bridge import CanSerialBridge  # noqa: E402
from bench.sim.factory import build_devices  # noqa: E402
from drivers import acs_protocol as proto  # noqa: E402
from drivers.acs_board import AcsBoard  # noqa: E402
from drivers.can_serial import open_can_serial  # noqa: E402
from tests.conftest import ROOT, SIM_CONFIG  # noqa: E402
from tests.golden.canbus import Capture, unique_channel  # noqa: E402

DOC = ROOT / "docs" / "acs-board-protocol.md"
STREAM_S = 5.0  # run s streamed per test
ODR_HZ = 200
WRAP_MARGIN_S = 2.5  # the stream starts this long before the board clock wraps (2^32 µs)
CAPTURE_WAIT_S = 5.0  # wall s for the capture bus to receive what the driver has already read


def test_document_crc_check_value():
    assert crc16_ccitt(b"123456789") == 0x31C3


def test_worked_examples_are_in_the_document_and_decode_as_it_says():
    text = DOC.read_text(encoding="utf-8")
    assert all(f"`{hex_}`" in text for hex_ in EXAMPLES.values())
    assert DATA_EXAMPLE in text
    doc = DocDecoder()
    doc.feed(b"".join(bytes.fromhex(h) for h in EXAMPLES.values()) + bytes.fromhex(DATA_EXAMPLE))
    assert (doc.crc_errors, doc.garbage_bytes) == (0, 0)
    assert doc.frames == [(0x10, b""), (0x13, bytes([200, 0])), (0x93, b""), (0x7F, bytes([0x13, 3])),
                          (0x97, bytes.fromhex("64 00 01 00 00 00 C2 01 00"))]
    assert parse_config(doc.frames[-1][1]) == {"odr_hz": 100, "moving_avg_n": 1, "streaming": False,
                                               "sensor_power": False, "baud": 115200}
    assert doc.samples == [DATA_EXAMPLE_DECODED]


def test_worked_examples_against_the_driver_codec():
    for hex_ in EXAMPLES.values():  # the driver's encoder builds the same bytes
        raw = bytes.fromhex(hex_)
        assert proto.encode_frame(raw[2], raw[4:-2]) == raw
    batch = proto.FrameDecoder(accept_unknown_types=True).feed(bytes.fromhex(DATA_EXAMPLE))
    assert batch.frames_ok == 1 and batch.crc_errors == 0
    for key, value in DATA_EXAMPLE_DECODED.items():
        assert np.array_equal(getattr(batch, key)[0], value), key
    # a one-bit error anywhere is a CRC error for both decoders
    bad = bytearray(bytes.fromhex(DATA_EXAMPLE))
    bad[20] ^= 0x04
    doc = DocDecoder()
    doc.feed(bytes(bad))
    assert (doc.crc_errors, doc.samples) == (1, [])
    assert proto.FrameDecoder().feed(bytes(bad)).crc_errors == 1


class TeePort:
    """A serial port that keeps a copy of every byte read and written."""

    def __init__(self, port) -> None:
        self._port = port
        self.rx = bytearray()
        self.tx = bytearray()

    def read(self, size: int = 1) -> bytes:
        data = self._port.read(size)
        self.rx += data
        return data

    def write(self, data) -> int:
        self.tx += bytes(data)
        return self._port.write(data)

    def __getattr__(self, name):
        return getattr(self._port, name)


def _run_session(board: AcsBoard, clock) -> tuple[list, dict, dict, int]:
    """Configure, stream STREAM_S across the board clock's wrap, stop; (batches, identity, config, BIT mask)."""
    identity = board.identify()
    board.sensor_power(True)
    board.set_odr(ODR_HZ)
    board.set_moving_average(4)
    bit = board.run_bit()
    config = board.get_config()
    clock.sleep_until(BOARD_TIME_WRAP * 1e-6 - WRAP_MARGIN_S)
    board.start_stream()
    batches = []
    t_end = clock.now() + STREAM_S
    while clock.now() < t_end - 1e-9:
        clock.sleep_until(min(clock.now() + 1.0, t_end))
        batches.append(board.poll())
    board.stop_stream()
    batches.append(board.poll())
    return batches, identity, config, bit


def _assert_same(doc: DocDecoder, batches: list, identity: dict, config: dict, bit: int) -> None:
    """The document's decoder saw what the driver decoded, sample by sample, and the same replies."""
    assert (doc.crc_errors, doc.garbage_bytes, doc.dropped_frames) == (0, 0, 0)
    n = sum(b.counter.size for b in batches)
    assert n == round(STREAM_S * ODR_HZ) and len(doc.samples) == n
    for key in ("counter", "board_time_s", "gyro_dps", "accel_g", "mag_ut", "temp_degc", "status"):
        driver = np.concatenate([getattr(b, key) for b in batches])
        ours = np.array([s[key] for s in doc.samples])
        np.testing.assert_array_equal(ours, driver, err_msg=key)
    t = np.array([s["board_time_s"] for s in doc.samples])
    assert t[0] < BOARD_TIME_WRAP * 1e-6 < t[-1]  # the stream crossed the 2^32 µs wrap
    assert np.allclose(np.diff(t), 1.0 / ODR_HZ, atol=2e-6)
    acks = {ftype: payload for ftype, payload in doc.frames if ftype & ACK_BIT}
    assert set(acks) == {c | ACK_BIT for c in COMMANDS.values()}  # every command of the session acknowledged
    assert acks[COMMANDS["IDENTIFY"] | ACK_BIT].decode("ascii") == ";".join(
        identity[k] for k in ("vendor", "model", "serial", "firmware"))
    assert parse_config(acks[COMMANDS["GET_CONFIG"] | ACK_BIT]) == config
    assert struct.unpack("<H", acks[COMMANDS["RUN_BIT"] | ACK_BIT]) == (bit,)
    assert config["odr_hz"] == ODR_HZ and config["moving_avg_n"] == 4 and config["sensor_power"]


def _assert_commands(tx: bytes) -> None:
    """What the host sent decodes, by the document, as the session's commands in order."""
    cmds = DocDecoder()
    cmds.feed(tx)
    assert (cmds.crc_errors, cmds.garbage_bytes) == (0, 0)
    names = {v: k for k, v in COMMANDS.items()}
    assert [names[t] for t, _ in cmds.frames] == ["IDENTIFY", "SENSOR_POWER", "SET_ODR", "SET_MOVING_AVG", "RUN_BIT",
                                                  "GET_CONFIG", "START_STREAM", "STOP_STREAM"]
    assert cmds.frames[1][1] == b"\x01" and cmds.frames[2][1] == struct.pack("<H", ODR_HZ)


def test_doc_decoder_agrees_with_the_driver_over_the_sim_serial_link(sim_board):
    _, clock, url = sim_board
    port = TeePort(serial.serial_for_url(url, baudrate=115200, timeout=0.5))
    board = AcsBoard(port, timeout_s=0.5)
    try:
        batches, identity, config, bit = _run_session(board, clock)
    finally:
        board.close()
    doc = DocDecoder()
    for i in range(0, len(port.rx), 37):  # any chunking: 37-byte pieces never align with frames
        doc.feed(bytes(port.rx[i:i + 37]))
    _assert_same(doc, batches, identity, config, bit)
    _assert_commands(bytes(port.tx))


def test_doc_decoder_agrees_with_the_driver_over_can():
    clock = VirtualClock()
    device = build_devices(load_config(SIM_CONFIG), clock, ["acs_board"])["acs_board"].device
    channel = unique_channel("acs-doc-can")
    cap = Capture(channel)
    bridge = CanSerialBridge(device, channel, node=BOARD_NODE)
    board = AcsBoard(open_can_serial(f"can://virtual/{channel}?node={BOARD_NODE}", 0.5, clock), timeout_s=0.5)
    try:
        batches, identity, config, bit = _run_session(board, clock)
        n = sum(b.counter.size for b in batches)
        doc = DocDecoder()
        seen = 0
        deadline = time.monotonic() + CAPTURE_WAIT_S
        while True:  # the capture bus receives the same frames on its own thread
            frames = cap.frames(seen)
            seen += len(frames)
            for cob, data in frames:  # zero-length frames are sync markers: no stream bytes
                if cob == BOARD_TO_HOST:
                    doc.feed(data)
            if len(doc.samples) >= n and len(doc.frames) >= len(COMMANDS) or time.monotonic() > deadline:
                break
            time.sleep(0.01)
        _assert_same(doc, batches, identity, config, bit)
        host = cap.frames(0, {HOST_TO_BOARD})
        assert all(1 <= len(d) <= 8 for _, d in host)
        _assert_commands(b"".join(d for _, d in host))
    finally:
        board.close()
        bridge.close()
        cap.close()
    assert bridge.error is None
