"""ACS/sensor-board wire protocol: frame layout as data, encoders, and a batch stream decoder.

Frame: sync ``A5 5A`` | type u8 | len u8 | payload (little-endian fields) | CRC-16/XMODEM over
type, len and payload, sent MSB first. A data frame is 38 bytes. Full specification, with the
sources of every scale: ``docs/acs-board-protocol.md``. Used by the driver (board -> host) and by
the simulator (host -> board), so it knows every frame type.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from enum import IntEnum, IntFlag

import numpy as np

from drivers.errors import ProtocolError
from drivers.crc import crc16_xmodem, crc16_xmodem_rows

SYNC = b"\xA5\x5A"
HEADER_LEN = 4  # sync, type, len
OVERHEAD = 6  # header + CRC
MAX_PAYLOAD = 128  # longest payload of a non-data frame (identity strings)


class FrameType(IntEnum):
    DATA = 0x01
    IDENTIFY = 0x10
    START_STREAM = 0x11
    STOP_STREAM = 0x12
    SET_ODR = 0x13
    SET_MOVING_AVG = 0x14
    RUN_BIT = 0x15
    SENSOR_POWER = 0x16
    GET_CONFIG = 0x17
    NAK = 0x7F


COMMANDS = tuple(t for t in FrameType if 0x10 <= t < 0x7F)
KNOWN_TYPES = frozenset([int(FrameType.DATA), int(FrameType.NAK)] + [int(c) for c in COMMANDS] + [int(c) | 0x80 for c in COMMANDS])
COMMAND_PAYLOAD_LEN = {
    FrameType.IDENTIFY: 0, FrameType.START_STREAM: 0, FrameType.STOP_STREAM: 0, FrameType.SET_ODR: 2,
    FrameType.SET_MOVING_AVG: 1, FrameType.RUN_BIT: 0, FrameType.SENSOR_POWER: 1, FrameType.GET_CONFIG: 0,
}
"""Payload length (bytes) of every command; any other length is NAKed BAD_LENGTH."""
MOVING_AVG_MAX = 100  # moving-average lengths 1..100 (ESTCube-2 section 3.3 swept N = 1..100)


class NakCode(IntEnum):
    UNKNOWN_COMMAND = 1
    BAD_LENGTH = 2
    BAD_VALUE = 3
    NOT_ALLOWED_IN_STATE = 4
    CRC_ERROR = 5


class Status(IntFlag):
    STREAMING = 1
    SENSOR_POWER = 2
    BIT_FAILED = 4
    SATURATED = 8
    OVERRUN = 16


class BitFailure(IntFlag):
    """Bits of the RUN_BIT reply's failed-subsystem mask."""

    GYRO = 1
    ACCEL = 2
    MAG = 4
    TEMPERATURE = 8
    SUPPLY = 16


# Scales (physical value per least significant bit):
GYRO_DPS_PER_LSB = 250.0 / 32768  # MPU-6000 ±250 deg/s, 16 bit (ESTCube-2 Table 2.1: 0.0076 deg/s)
ACCEL_G_PER_LSB = 2.0 / 32768  # MPU-6000 ±2 g, 16 bit: 61 µg (ESTCube-2 Table 2.2)
MAG_UT_PER_LSB = 100.0 / 6842  # LIS3MDL ±4 gauss, 6842 LSB/gauss; 1 gauss = 100 µT (ESTCube-2 Table 2.3: 14.6 nT)
TEMP_DEGC_PER_LSB = 0.01  # board firmware convention: centi-degrees Celsius
BOARD_TIME_S_PER_LSB = 1e-6  # board clock in µs, wraps at 2**32 (71.6 min)


@dataclass(frozen=True)
class DataField:
    """One field of the data frame: raw name, numpy dtype, count, byte offset in the frame,
    scale to physical units, units, and the name of the decoded (physical) array."""

    raw: str
    dtype: str
    count: int
    offset: int
    scale: float
    units: str
    decoded: str


DATA_LAYOUT: tuple[DataField, ...] = (
    DataField("counter", "<u2", 1, 4, 1.0, "1", "counter"),
    DataField("board_time_us", "<u4", 1, 6, BOARD_TIME_S_PER_LSB, "s", "board_time_s"),
    DataField("gyro", "<i2", 3, 10, GYRO_DPS_PER_LSB, "deg/s", "gyro_dps"),
    DataField("accel", "<i2", 3, 16, ACCEL_G_PER_LSB, "g", "accel_g"),
    DataField("mag", "<i2", 3, 22, MAG_UT_PER_LSB, "uT", "mag_ut"),
    DataField("temp", "<i2", 3, 28, TEMP_DEGC_PER_LSB, "degC", "temp_degc"),
    DataField("status", "<u2", 1, 34, 1.0, "1", "status"),
)
"""The data frame, once. Encoder, decoder and docs derive from this table."""

DATA_PAYLOAD_LEN = 32
DATA_FRAME_LEN = OVERHEAD + DATA_PAYLOAD_LEN  # 38
CRC_OFFSET = HEADER_LEN + DATA_PAYLOAD_LEN  # 36

DATA_DTYPE = np.dtype(
    {
        "names": ["sync", "type", "len"] + [f.raw for f in DATA_LAYOUT] + ["crc"],
        "formats": ["S2", "u1", "u1"] + [(f.dtype, (f.count,)) if f.count > 1 else f.dtype for f in DATA_LAYOUT] + [">u2"],
        "offsets": [0, 2, 3] + [f.offset for f in DATA_LAYOUT] + [CRC_OFFSET],
        "itemsize": DATA_FRAME_LEN,
    }
)
_RAW_LIMITS = {"gyro": (-32768, 32767), "accel": (-32768, 32767), "mag": (-32768, 32767), "temp": (-32768, 32767)}


def encode_frame(ftype: int, payload: bytes = b"") -> bytes:
    """One frame of type ``ftype`` with ``payload`` (at most 255 bytes)."""
    if len(payload) > 255:
        raise ValueError(f"payload of {len(payload)} bytes exceeds 255")
    body = bytes([ftype & 0xFF, len(payload)]) + bytes(payload)
    return SYNC + body + crc16_xmodem(body).to_bytes(2, "big")


def encode_data_frames(counter, board_time_us, gyro_raw, accel_raw, mag_raw, temp_raw, status) -> bytes:
    """``n`` data frames from raw integer arrays ((n,) or (n, 3)) concatenated, without a Python loop."""
    counter = np.asarray(counter)
    n = counter.shape[0]
    frames = np.zeros(n, dtype=DATA_DTYPE)
    frames["sync"] = SYNC
    frames["type"] = FrameType.DATA
    frames["len"] = DATA_PAYLOAD_LEN
    for name, values in (("counter", counter), ("board_time_us", board_time_us), ("gyro", gyro_raw), ("accel", accel_raw),
                         ("mag", mag_raw), ("temp", temp_raw), ("status", status)):
        frames[name] = values
    raw = frames.view(np.uint8).reshape(n, DATA_FRAME_LEN)
    crc = crc16_xmodem_rows(raw[:, 2:CRC_OFFSET])
    raw[:, CRC_OFFSET] = crc >> 8
    raw[:, CRC_OFFSET + 1] = crc & 0xFF
    return raw.tobytes()


def physical_to_raw(gyro_dps, accel_g, mag_ut, temp_degc):
    """Quantise physical values (n, 3) to the frame's int16 counts, saturating at the range limits.

    Returns ``(gyro, accel, mag, temp, saturated)`` where ``saturated`` (n,) bool marks rows in
    which a gyro, accelerometer or magnetometer component hit its limit.
    """
    out = []
    saturated = None
    for name, values, scale in (("gyro", gyro_dps, GYRO_DPS_PER_LSB), ("accel", accel_g, ACCEL_G_PER_LSB),
                                ("mag", mag_ut, MAG_UT_PER_LSB), ("temp", temp_degc, TEMP_DEGC_PER_LSB)):
        lo, hi = _RAW_LIMITS[name]
        counts = np.asarray(values, dtype=np.float64) / scale  # a new array: rounded and clipped in place
        np.rint(counts, out=counts)
        if name != "temp":
            s = (~((counts >= lo) & (counts <= hi))).any(axis=1)  # NaN counts as saturated, as before clipping
            saturated = s if saturated is None else saturated | s
        np.clip(counts, lo, hi, out=counts)
        out.append(counts.astype(np.int16))
    return (*out, saturated)


@dataclass
class DecodedBatch:
    """What one :meth:`FrameDecoder.feed` produced. Arrays have one row per good data frame."""

    counter: np.ndarray
    board_time_s: np.ndarray
    gyro_dps: np.ndarray
    accel_g: np.ndarray
    mag_ut: np.ndarray
    temp_degc: np.ndarray
    status: np.ndarray
    replies: list[tuple[int, bytes]] = field(default_factory=list)
    crc_errors: int = 0
    garbage_bytes: int = 0
    dropped_frames: int = 0
    frames_ok: int = 0

    @classmethod
    def empty(cls) -> "DecodedBatch":
        z3 = np.zeros((0, 3))
        return cls(np.zeros(0, np.uint16), np.zeros(0), z3, z3.copy(), z3.copy(), z3.copy(), np.zeros(0, np.uint16))


_EMPTY_ROWS = np.zeros((0, DATA_FRAME_LEN), dtype=np.uint8)
_DATA_HEADER_CRC = crc16_xmodem(bytes([FrameType.DATA, DATA_PAYLOAD_LEN]))
_PLAUSIBLE = np.zeros(256, dtype=bool)
_PLAUSIBLE[list(KNOWN_TYPES)] = True


class FrameDecoder:
    """Streaming batch decoder. Feed it bytes in any chunking; it returns decoded frames.

    Resynchronises after garbage; counts CRC errors (frames with a plausible header whose CRC
    fails), garbage bytes (bytes skipped that were not part of a good frame, including those of
    corrupted frames), dropped frames (gaps in the data-frame counter, modulo 65536, also across
    feeds) and unwraps the board's 32-bit µs clock. Cumulative totals are attributes.
    """

    def __init__(self, accept_unknown_types: bool = False) -> None:
        """``accept_unknown_types``: treat frames of any type as candidates (the board side uses this
        so that it can NAK unknown commands; the host side skips them as garbage)."""
        self._plausible = np.ones(256, dtype=bool) if accept_unknown_types else _PLAUSIBLE
        self._tail = b""
        self._last_counter: int | None = None
        self._last_time_us: int | None = None
        self._wraps = 0
        self.crc_errors = 0
        self.garbage_bytes = 0
        self.dropped_frames = 0
        self.frames_ok = 0

    @property
    def pending_bytes(self) -> int:
        """Bytes held back until more data shows whether they start a frame."""
        return len(self._tail)

    def feed(self, data: bytes) -> DecodedBatch:
        """Decode ``data`` (appended to the bytes held back from the previous feed)."""
        buf_bytes = self._tail + bytes(data)
        buf = np.frombuffer(buf_bytes, dtype=np.uint8)
        size = buf.size
        cand = np.flatnonzero((buf[:-1] == 0xA5) & (buf[1:] == 0x5A))
        # Stop points: places from which the rest of the buffer is undecidable (an incomplete
        # header or frame, or a trailing A5 that may be half a sync word) unless they turn out to
        # lie inside an accepted frame.
        stops = [size - 1] if size and buf[-1] == 0xA5 else []
        header_ok = cand + HEADER_LEN <= size
        if not header_ok.all():
            stops.append(int(cand[~header_ok][0]))
        cand = cand[header_ok]
        ftype = buf[cand + 2]
        flen = buf[cand + 3].astype(np.int64)
        plausible = self._plausible[ftype] & np.where(ftype == FrameType.DATA, flen == DATA_PAYLOAD_LEN, flen <= MAX_PAYLOAD)
        cand, ftype, flen = cand[plausible], ftype[plausible], flen[plausible]
        ends = cand + OVERHEAD + flen
        complete = ends <= size
        if not complete.all():
            stops.extend(cand[~complete].tolist())
            cand, ftype, ends = cand[complete], ftype[complete], ends[complete]

        good = np.zeros(cand.size, dtype=bool)
        is_data = ftype == FrameType.DATA
        d_idx = np.flatnonzero(is_data)
        rows = _EMPTY_ROWS
        if d_idx.size:
            # gather whole frames as rows (one 38-byte copy each), check payload+CRC in one pass
            rows = np.lib.stride_tricks.sliding_window_view(buf, DATA_FRAME_LEN)[cand[d_idx]]
            good[d_idx] = crc16_xmodem_rows(rows[:, HEADER_LEN:], _DATA_HEADER_CRC) == 0
        for i in np.flatnonzero(~is_data):  # replies and commands are rare: a loop is fine
            s, e = int(cand[i]), int(ends[i])
            good[i] = crc16_xmodem(buf_bytes[s + 2 : e - 2]) == int.from_bytes(buf_bytes[e - 2 : e], "big")

        g_start, g_end, g_type = cand[good], ends[good], ftype[good]
        data_rows = rows[good[d_idx]]
        if g_start.size > 1 and np.any(g_end[:-1] > g_start[1:]):  # rare: overlapping valid frames
            accept = _non_overlapping(g_start, g_end)
            data_rows = data_rows[accept[g_type == FrameType.DATA]]
            g_start, g_end, g_type = g_start[accept], g_end[accept], g_type[accept]
        # the first stop point outside every accepted frame ends what this feed can decide
        limit = size
        if stops:
            st = np.unique(np.asarray(stops, dtype=np.int64))
            if g_start.size:
                st = st[~_inside(st, g_start, g_end)]
            if st.size:
                limit = int(st[0])
        if g_start.size and g_start[-1] >= limit:  # frames after the stop point wait for the next feed
            keep = g_start < limit
            data_rows = data_rows[keep[g_type == FrameType.DATA]]
            g_start, g_end, g_type = g_start[keep], g_end[keep], g_type[keep]
        bad = cand[~good]
        bad = bad[bad < limit]
        if bad.size and g_start.size:
            bad = bad[~_inside(bad, g_start, g_end)]
        crc_errors = int(bad.size)
        garbage = limit - int((g_end - g_start).sum())
        self._tail = buf_bytes[limit:]

        batch = self._decode_data(data_rows)
        other = g_type != FrameType.DATA
        if other.any():
            for s, e, t in zip(g_start[other].tolist(), g_end[other].tolist(), g_type[other].tolist()):
                batch.replies.append((t, buf_bytes[s + HEADER_LEN : e - 2]))
        batch.crc_errors = crc_errors
        batch.garbage_bytes = garbage
        batch.frames_ok = int(g_start.size)
        self.crc_errors += crc_errors
        self.garbage_bytes += garbage
        self.frames_ok += batch.frames_ok
        self.dropped_frames += batch.dropped_frames
        return batch

    def _decode_data(self, rows: np.ndarray) -> DecodedBatch:
        """Decode good data frames given as an (n, 38) contiguous byte matrix."""
        n = rows.shape[0]
        if n == 0:
            return DecodedBatch.empty()
        frames = rows.view(DATA_DTYPE).reshape(n)
        counter = frames["counter"].astype(np.uint16)
        c = counter.astype(np.int64)
        prev = np.concatenate(([self._last_counter], c[:-1])) if self._last_counter is not None else None
        if prev is not None:
            step = (c - prev) % 65536
        else:
            step = np.concatenate(([1], (c[1:] - c[:-1]) % 65536))
        dropped = int(np.where(step == 0, 0, step - 1).sum())
        self._last_counter = int(c[-1])
        t_us = frames["board_time_us"].astype(np.int64)
        prev_t = np.concatenate(([self._last_time_us if self._last_time_us is not None else t_us[0]], t_us[:-1]))
        wraps = self._wraps + np.cumsum(t_us < prev_t)
        self._wraps = int(wraps[-1])
        self._last_time_us = int(t_us[-1])
        board_time_s = (t_us + wraps * 2**32) * BOARD_TIME_S_PER_LSB
        out = {"counter": counter, "board_time_s": board_time_s, "status": frames["status"].astype(np.uint16)}
        for f in DATA_LAYOUT:
            if f.count == 3:
                out[f.decoded] = frames[f.raw].astype(np.float64) * f.scale
        return DecodedBatch(**out, dropped_frames=dropped)


def _inside(points: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Which ``points`` fall strictly after the start and before the end of a (sorted, disjoint) frame."""
    j = np.searchsorted(starts, points, side="right") - 1
    return (j >= 0) & (points > starts[np.maximum(j, 0)]) & (points < ends[np.maximum(j, 0)])


def _non_overlapping(starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Greedy left-to-right choice of CRC-valid frames that do not overlap (rare path)."""
    accept = np.zeros(starts.size, dtype=bool)
    end = -1
    for i, (s, e) in enumerate(zip(starts.tolist(), ends.tolist())):
        if s >= end:
            accept[i] = True
            end = e
    return accept


# ---- replies ----------------------------------------------------------------------------------
def reply_type(command: int) -> int:
    """Frame type of the acknowledgement of ``command``."""
    return int(command) | 0x80


def frame_name(ftype: int) -> str:
    """Readable name of a frame type: ``IDENTIFY``, ``IDENTIFY_ACK``, ``NAK``, or ``0x3C``."""
    if ftype in FrameType._value2member_map_:
        return FrameType(ftype).name
    if ftype & 0x80 and (ftype & 0x7F) in FrameType._value2member_map_:
        return FrameType(ftype & 0x7F).name + "_ACK"
    return f"0x{ftype:02X}"


def parse_nak(payload: bytes) -> tuple[int, int]:
    """(refused command, NakCode value); :class:`ProtocolError` for a payload of another length."""
    if len(payload) != 2:
        raise ProtocolError(f"acs_board: NAK payload must be 2 bytes, got {len(payload)}")
    return payload[0], payload[1]


def parse_identity(payload: bytes) -> dict[str, str]:
    """IDENTIFY reply: ASCII ``vendor;model;serial;firmware``."""
    parts = payload.decode("ascii", "replace").split(";")
    parts += [""] * (4 - len(parts))
    return dict(zip(("vendor", "model", "serial", "firmware"), parts[:3] + [";".join(parts[3:])]))


CONFIG_FORMAT = "<HBBBI"


def parse_config(payload: bytes) -> dict:
    """GET_CONFIG reply: output data rate (Hz), moving-average N, streaming, sensor power, baud rate
    (:class:`ProtocolError` for a payload of another length)."""
    if len(payload) != struct.calcsize(CONFIG_FORMAT):
        raise ProtocolError(f"acs_board: GET_CONFIG payload must be {struct.calcsize(CONFIG_FORMAT)} bytes, got {len(payload)}")
    odr, n, streaming, power, baud = struct.unpack(CONFIG_FORMAT, payload)
    return {"odr_hz": odr, "moving_avg_n": n, "streaming": bool(streaming), "sensor_power": bool(power), "baud": baud}


def encode_config(odr_hz: int, moving_avg_n: int, streaming: bool, sensor_power: bool, baud: int) -> bytes:
    return struct.pack(CONFIG_FORMAT, odr_hz, moving_avg_n, int(streaming), int(sensor_power), baud)


def parse_bit(payload: bytes) -> int:
    """RUN_BIT reply: failed-subsystem mask (:class:`BitFailure` bits; 0 = passed); :class:`ProtocolError` if not 2 bytes."""
    if len(payload) != 2:
        raise ProtocolError(f"acs_board: RUN_BIT payload must be 2 bytes, got {len(payload)}")
    return struct.unpack("<H", payload)[0]
