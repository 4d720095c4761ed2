"""ACS/sensor-board wire protocol: our board's frame description and its named constants.

Frame: sync ``A5 5A`` | type u8 | len u8 | payload (little-endian fields) | CRC-16/XMODEM over
type, len and payload, sent MSB first. A data frame is 38 bytes. The format is data,
``drivers/frames/acs_board.yaml`` (a frame description, ``drivers/board_frames.py``); the
specification with the sources of every scale is ``docs/acs-board-protocol.md``. This module
names our frame types, NAK codes, status and BIT bits and keeps the codec functions of our
format (encode, physical to raw, decoder) under the names the tests and benchmarks use.
"""

from __future__ import annotations

from enum import IntEnum, IntFlag

from drivers import board_frames
from drivers import frame_decoder
from drivers.frame_decoder import DecodedBatch  # noqa: F401 - part of this module's API
from drivers.frame_schema import builtin_description

DESCRIPTION = builtin_description("acs_board")
"""Our board's frames as data (``drivers/frames/acs_board.yaml``): encoder, decoder, dtype and the
names below derive from it."""

SYNC = DESCRIPTION.sync
HEADER_LEN = DESCRIPTION.header_len  # sync, type, len
OVERHEAD = DESCRIPTION.overhead  # header + CRC
MAX_PAYLOAD = DESCRIPTION.max_payload  # longest payload of a non-data frame (identity strings)

FrameType = IntEnum("FrameType", [("DATA", DESCRIPTION.data_id)] + [(c.op.upper(), c.id) for c in DESCRIPTION.commands.values()]
                    + [("NAK", DESCRIPTION.nak.id)])
"""Frame types by name: DATA, the commands (IDENTIFY 0x10 ... GET_CONFIG 0x17), NAK."""
COMMANDS = tuple(t for t in FrameType if t.name not in ("DATA", "NAK"))
KNOWN_TYPES = DESCRIPTION.known_types
COMMAND_PAYLOAD_LEN = {FrameType[c.op.upper()]: board_frames.items_len(c.payload) for c in DESCRIPTION.commands.values()}
"""Payload length (bytes) of every command; any other length is NAKed BAD_LENGTH."""
MOVING_AVG_MAX = 100  # moving-average lengths 1..100 (ESTCube-2 section 3.3 swept N = 1..100)

NakCode = IntEnum("NakCode", [(k.upper(), v) for k, v in DESCRIPTION.nak.codes.items()])
"""NAK codes: UNKNOWN_COMMAND 1, BAD_LENGTH 2, BAD_VALUE 3, NOT_ALLOWED_IN_STATE 4, CRC_ERROR 5."""
Status = IntFlag("Status", [(k.upper(), v) for k, v in DESCRIPTION.status_bits.items()])
"""Status word bits: STREAMING 1, SENSOR_POWER 2, BIT_FAILED 4, SATURATED 8, OVERRUN 16."""


class BitFailure(IntFlag):
    """Bits of the RUN_BIT reply's failed-subsystem mask."""

    GYRO = 1
    ACCEL = 2
    MAG = 4
    TEMPERATURE = 8
    SUPPLY = 16


# Scales (physical value per least significant bit), from the description:
GYRO_DPS_PER_LSB = DESCRIPTION.field("gyro").scale  # MPU-6000 ±250 deg/s, 16 bit (ESTCube-2 Table 2.1: 0.0076 deg/s)
ACCEL_G_PER_LSB = DESCRIPTION.field("accel").scale  # MPU-6000 ±2 g, 16 bit: 61 µg (ESTCube-2 Table 2.2)
MAG_UT_PER_LSB = DESCRIPTION.field("mag").scale  # LIS3MDL ±4 gauss, 6842 LSB/gauss; 1 gauss = 100 µT (ESTCube-2 Table 2.3: 14.6 nT)
TEMP_DEGC_PER_LSB = DESCRIPTION.field("temp").scale  # board firmware convention: centi-degrees Celsius
BOARD_TIME_S_PER_LSB = DESCRIPTION.field("board_time").scale  # board clock in µs, wraps at 2**32 (71.6 min)

DATA_PAYLOAD_LEN = DESCRIPTION.data_payload_len  # 32
DATA_FRAME_LEN = DESCRIPTION.data_frame_len  # 38
CRC_OFFSET = DESCRIPTION.check_at  # 36
DATA_DTYPE = DESCRIPTION.data_dtype


def encode_frame(ftype: int, payload: bytes = b"") -> bytes:
    """One frame of type ``ftype`` with ``payload`` (at most 255 bytes)."""
    return DESCRIPTION.encode_frame(ftype, payload)


def encode_data_frames(counter, board_time_us, gyro_raw, accel_raw, mag_raw, temp_raw, status) -> bytes:
    """``n`` data frames from raw integer arrays ((n,) or (n, 3)) concatenated, without a Python loop."""
    return DESCRIPTION.encode_data({"counter": counter, "board_time": board_time_us, "gyro": gyro_raw, "accel": accel_raw,
                                    "mag": mag_raw, "temp": temp_raw, "status": status})


def physical_to_raw(gyro_dps, accel_g, mag_ut, temp_degc):
    """Quantise physical values (n, 3) to the frame's int16 counts, saturating at the range limits.

    Returns ``(gyro, accel, mag, temp, saturated)`` where ``saturated`` (n,) bool marks rows in
    which a gyro, accelerometer or magnetometer component hit its limit.
    """
    raw, saturated = DESCRIPTION.to_raw({"gyro": gyro_dps, "accel": accel_g, "mag": mag_ut, "temp": temp_degc})
    return raw["gyro"], raw["accel"], raw["mag"], raw["temp"], saturated


class FrameDecoder(frame_decoder.FrameDecoder):
    """Streaming batch decoder of our board's frames (:class:`drivers.frame_decoder.FrameDecoder` on
    :data:`DESCRIPTION`)."""

    def __init__(self, accept_unknown_types: bool = False) -> None:
        super().__init__(DESCRIPTION, accept_unknown_types)


# ---- replies ----------------------------------------------------------------------------------
def reply_type(command: int) -> int:
    """Frame type of the acknowledgement of ``command``."""
    return DESCRIPTION.command_by_id(int(command)).reply.id


def frame_name(ftype: int) -> str:
    """Readable name of a frame type: ``IDENTIFY``, ``IDENTIFY_ACK``, ``NAK``, or ``0x3C``."""
    return DESCRIPTION.frame_name(ftype)


def parse_nak(payload: bytes) -> tuple[int, int]:
    """(refused command, NakCode value); :class:`ProtocolError` for a payload of another length."""
    command, code = board_frames.parse_nak(DESCRIPTION, payload)
    return int(command), code


def parse_identity(payload: bytes) -> dict[str, str]:
    """IDENTIFY reply: ASCII ``vendor;model;serial;firmware``."""
    return board_frames.parse_reply(DESCRIPTION, "identify", payload)


def parse_config(payload: bytes) -> dict:
    """GET_CONFIG reply: output data rate (Hz), moving-average N, streaming, sensor power, baud rate
    (:class:`ProtocolError` for a payload of another length)."""
    return board_frames.parse_reply(DESCRIPTION, "get_config", payload)


def encode_config(odr_hz: int, moving_avg_n: int, streaming: bool, sensor_power: bool, baud: int) -> bytes:
    return board_frames.build_reply(DESCRIPTION, "get_config", {"odr_hz": odr_hz, "moving_avg_n": moving_avg_n,
                                                                 "streaming": int(streaming), "sensor_power": int(sensor_power), "baud": baud})


def parse_bit(payload: bytes) -> int:
    """RUN_BIT reply: failed-subsystem mask (:class:`BitFailure` bits; 0 = passed); :class:`ProtocolError` if not 2 bytes."""
    return board_frames.parse_reply(DESCRIPTION, "run_bit", payload)["failed_mask"]
