"""Golden frames of a real Xsens MTi-300 decoded through frame descriptions (docs/golden/xsens-mtdata2.md).

The payloads are the bytes a real MTi-300 sent, recorded and decoded by Xsens MT Manager; the
expected values are MT Manager's. The Xbus frame around each payload and its checksum are built
here from the rule of ../shared/protocols.md section 6, not by our encoder. The descriptions are
plain YAML for the two output configurations of the recording; nothing of configs/frames/ or of
the codec's constants is imported.
"""

from __future__ import annotations

import numpy as np
import pytest

from bench.board_frames import load_frame_description
from drivers.frame_decoder import FrameDecoder

X3 = bytes.fromhex(
    "10 20 02 8D 90 10 60 04 00 54 DB F1 20 10 10 3F 7F 89 11 BC 11 1D FA 3B A0 CE F0 BD 73 25 73 40 20 0C BD DC F9 D0 "
    "BE 3C 86 19 41 1D 0B 47 40 10 0C B9 8D B0 00 B9 F1 48 00 3C C9 04 30 40 30 0C BC B9 89 2E BB 09 8C 00 3C A7 08 00 "
    "80 20 0C BA 63 BC 01 BC 04 D6 3F BB 6D E3 FE 80 30 10 3F 80 00 01 B5 91 C0 00 B7 2A 08 00 B6 98 40 00 E0 20 04 00 "
    "40 00 03")
X4 = bytes.fromhex(
    "10 20 02 91 8D 10 60 04 01 36 3F A6 20 10 10 3F 35 E0 42 3F 31 CD 15 BD 9F 49 DB BD A9 38 CF 40 20 0C BD 63 5A 90 "
    "41 1D 08 D4 3E 5F AA 50 40 10 0C B9 11 68 00 3C C9 01 00 3A 0F 7D 00 40 30 0C BC 3B 29 80 3C 35 FC 00 3C A4 6E 00 "
    "80 20 0C 3C AE A2 41 BB 56 D8 00 BA D5 AC 01 80 30 10 3F 80 00 00 37 DF 88 01 B6 89 80 00 B6 08 C0 00 C0 20 0C BE "
    "FB FB F2 3F 33 C4 85 BF A0 A2 C1 08 10 04 42 16 80 00 30 10 04 00 01 86 E1 E0 20 04 00 40 00 03")
X6 = bytes.fromhex("10 20 02 46 82 10 60 04 01 C4 FC 3E 20 10 10 3F 71 CE 6C BE A5 6B CF 3C 61 3B D8 BD 69 1D 25 E0 20 04 00 40 00 03")
G = 9.80665  # m/s^2 per g_n: the description records specific force in g


def xbus(payload: bytes, mid: int = 0x36) -> bytes:
    """``FA FF MID LEN payload CS``: every byte after the preamble sums to 0 mod 256 (protocols.md s6)."""
    body = bytes([0xFF, mid, len(payload)]) + payload
    return b"\xFA" + body + bytes([-sum(body) & 0xFF])


def item(name: str, xdi: int, size: int, field: str) -> str:
    return (f"    - {{name: id_{name}, type: u2, value: {xdi}}}\n    - {{name: size_{name}, type: u1, value: {size}}}\n"
            f"    - {field}\n")


HEAD = """schema: bench-board-frames/1
name: {name}
byte_order: big
sync: [0xFA, 0xFF]
header: [type, length]
check: {{algorithm: sum8_complement, from: 1}}
max_payload: 254
commands:
  identify: {{id: 0x00, reply: {{id: 0x01, payload: [{{name: serial, type: u4, format: hex}}]}}}}
  start_stream: {{id: 0x10, reply: {{id: 0x11}}}}
  stop_stream: {{id: 0x30, reply: {{id: 0x31}}}}
data:
  id: 0x36
  fields:
"""
COMMON = (item("counter", 0x1020, 2, "{name: counter, type: u2}") + item("time", 0x1060, 4, "{name: board_time, type: u4, scale: 1.0e-4, units: s}")
          + item("quat", 0x2010, 16, "{name: quat, type: f4, count: 4}") + item("acc", 0x4020, 12, "{name: accel, type: f4, count: 3, units: m/s^2}")
          + item("dv", 0x4010, 12, "{name: delta_v, type: f4, count: 3, units: m/s}")
          + item("free", 0x4030, 12, "{name: free_accel, type: f4, count: 3, units: m/s^2}")
          + item("gyr", 0x8020, 12, "{name: gyro, type: f4, count: 3, units: rad/s}") + item("dq", 0x8030, 16, "{name: delta_q, type: f4, count: 4}"))
STATUS = item("status", 0xE020, 4, "{name: status, type: u4}")
CONFIG_3 = HEAD.format(name="mti300-x3") + COMMON + STATUS
CONFIG_4 = (HEAD.format(name="mti300-x4") + COMMON + item("mag", 0xC020, 12, "{name: mag_au, type: f4, count: 3}")
            + item("temp", 0x0810, 4, "{name: temp, type: f4, units: degC}") + item("baro", 0x3010, 4, "{name: pressure, type: u4, units: Pa}") + STATUS)
CONFIG_6 = HEAD.format(name="mti300-x6") + item("counter", 0x1020, 2, "{name: counter, type: u2}") + \
    item("time", 0x1060, 4, "{name: board_time, type: u4, scale: 1.0e-4, units: s}") + item("quat", 0x2010, 16, "{name: quat, type: f4, count: 4}") + STATUS


@pytest.fixture(scope="module")
def descriptions(tmp_path_factory):
    out = {}
    for key, text in (("x3", CONFIG_3), ("x4", CONFIG_4), ("x6", CONFIG_6)):
        p = tmp_path_factory.mktemp("mti") / f"{key}.yaml"
        p.write_text(text, encoding="utf-8")
        out[key] = load_frame_description(p)
    return out


def test_x3_decodes_as_mt_manager_decoded_it(descriptions):
    d = descriptions["x3"]
    assert d.data_payload_len == len(X3) == 117
    b = FrameDecoder(d).feed(xbus(X3))
    assert b.frames_ok == 1 and b.crc_errors == b.garbage_bytes == b.layout_errors == 0
    assert b.counter.tolist() == [36240] and b.board_time_s[0] == pytest.approx(5561329e-4)
    np.testing.assert_allclose(b.columns["accel"][0] * G, [-0.10789835, -0.18410529, 9.81525326], rtol=1e-6)
    np.testing.assert_allclose(np.radians(b.columns["gyro"][0]), [-0.00086874, -0.00810772, -0.00362992], rtol=1e-5)
    assert b.columns["quat"][0, 0] == pytest.approx(0.99818522, abs=1e-8)
    assert b.status.tolist() == [0b00000000010000000000000000000011]


def test_x4_with_temperature_and_x6_decode(descriptions):
    b = FrameDecoder(descriptions["x4"]).feed(xbus(X4))
    assert b.counter.tolist() == [37261] and b.board_time_s[0] == pytest.approx(20332454e-4)
    assert b.columns["temp"].tolist() == [37.625] and b.columns["pressure"].tolist() == [100065]
    np.testing.assert_allclose(b.columns["accel"][0] * G, [-0.05550629, 9.81465530, 0.21842313], rtol=1e-6)
    np.testing.assert_allclose(np.radians(b.columns["gyro"][0]), [0.02131760, -0.00327826, -0.00163019], rtol=1e-5)
    np.testing.assert_allclose(b.columns["mag_au"][0], [-0.49215657, 0.70221740, -1.25496686], rtol=1e-6)
    b = FrameDecoder(descriptions["x6"]).feed(xbus(X6))
    assert b.counter.tolist() == [18050] and b.board_time_s[0] == pytest.approx(29686846e-4)
    np.testing.assert_allclose(b.columns["quat"][0], [0.94455600, -0.32308814, 0.01374718, -0.05691256], rtol=1e-6)


def test_a_message_of_another_output_configuration_is_not_misread(descriptions):
    """X3's message under X4's description, and X4's with a changed item id: skipped, never decoded."""
    dec = FrameDecoder(descriptions["x4"])
    b = dec.feed(xbus(X3) + xbus(X4))
    assert b.counter.tolist() == [37261] and b.garbage_bytes == len(xbus(X3))
    wrong = bytearray(X4)
    wrong[wrong.index(bytes.fromhex("08 10 04"))] = 0x09  # another item where the temperature was described
    b = dec.feed(xbus(bytes(wrong)))
    assert b.frames_ok == 0 and b.layout_errors == 1 and b.crc_errors == 0 and b.garbage_bytes == len(X4) + 5


def test_a_corrupted_checksum_is_counted(descriptions):
    frame = bytearray(xbus(X6))
    frame[-1] ^= 0xFF
    b = FrameDecoder(descriptions["x6"]).feed(bytes(frame) + xbus(X6))
    assert b.frames_ok == 1 and b.crc_errors == 1 and b.garbage_bytes == len(frame)
